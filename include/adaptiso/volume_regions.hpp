// adaptiso/volume_regions.hpp — boxes of voxels read straight from a volume file, so that a brick
// of a volume can be read without the rest (issue 38: the MPI ranks other than rank 0 read only
// their bricks).
//
// open_regions() looks at a file as read_volume() would and, when its samples lie in it as one
// uncompressed run of bytes — raw samples (RawOptions), NRRD with raw encoding in one data file
// (attached .nrrd or detached .nhdr, any byte skip, no line skip), NIfTI-1/-2 (.nii, .hdr/.img;
// scl_slope and scl_inter applied), MetaImage with one data file (.mha, .mhd, any HeaderSize) —
// returns a reader of boxes. read(box) gives the box's samples exactly as read_volume(path) holds
// them (the same bytes, x fastest), with the volume's spacing and direction and the origin at the
// box's first voxel, reading only the box's rows. Other files (compressed, text-encoded, one file
// per slice, DICOM, VTK) give nullopt: read them whole.
//
// Units: voxel index space for boxes. Throws what read_volume throws for a file it cannot read
// (InputError or OptionError, one line naming the file); read() throws InputError naming the box
// when the file no longer holds it (truncated since it was opened) or a float sample in it is NaN
// or infinite, and std::invalid_argument for a box outside the volume.
#pragma once
#include <cstdint>
#include <optional>
#include <string>

#include "adaptiso/volume.hpp"
#include "adaptiso/volume_io.hpp"

namespace adaptiso {

struct VolumeRegions {
  Volume header;             // dims, type, spacing, origin, direction; no samples
  std::string file;          // the file holding the samples
  std::uint64_t offset = 0;  // of the first sample in it
  bool swap = false;         // samples stored in the other byte order than this machine's
  // NIfTI's scl_slope and scl_inter: samples stored as `stored` become s × slope + inter, of
  // header.type, as read_volume makes them. None elsewhere.
  struct Scaling {
    ScalarType stored = ScalarType::u8;
    double slope = 1, inter = 0;
  };
  std::optional<Scaling> scaling;
  Volume read(const VoxelBox& box) const;
};

std::optional<VolumeRegions> open_regions(const std::string& path, const ReadOptions& options = {});

}  // namespace adaptiso
