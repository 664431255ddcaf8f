// Boxes of flat arrays (x fastest): what the region readers copy out of a volume in memory and
// the bricks copy out of their codes.
#pragma once
#include <cstddef>
#include <cstdint>

#include "adaptiso/volume.hpp"

namespace adaptiso::detail {

// Copies the box `from` (inclusive, within an array of dims `dims`) of a byte array of `size`-byte
// elements into a dense array.
void copy_box(const std::uint8_t* src, const Dims& dims, const VoxelBox& from, std::size_t size, std::uint8_t* dst);

// The box (inside the volume: not checked) of a volume in memory as a volume of its own: its
// samples, the volume's geometry, the origin at the box's first voxel, as VolumeRegions::read
// gives a box of a file.
Volume copy_box(const Volume& v, const VoxelBox& box);

}  // namespace adaptiso::detail
