// adaptiso/volume_regions.hpp — boxes of voxels read straight from a volume file, so that a brick
// of a volume can be read without the rest (issue 38: the MPI ranks other than rank 0 read only
// their bricks): by seeking in uncompressed files (VolumeRegions), slab by slab from a compressed
// stream or from the slice files of a DICOM series (VolumeStream).
//
// open_regions() looks at a file as read_volume() would and, when its samples lie in it as one
// uncompressed run of bytes — raw samples (RawOptions), NRRD with raw encoding in one data file
// (attached .nrrd or detached .nhdr, any byte skip, no line skip), NIfTI-1/-2 (.nii, .hdr/.img;
// scl_slope and scl_inter applied), MetaImage with one data file (.mha, .mhd, any HeaderSize) —
// returns a reader of boxes. read(box) gives the box's samples exactly as read_volume(path) holds
// them (the same bytes, x fastest), with the volume's spacing and direction and the origin at the
// box's first voxel, reading only the box's rows. Other files (compressed, text-encoded, one file
// per slice, DICOM, VTK) give nullopt: read them whole (or, compressed or DICOM, by open_stream).
//
// Units: voxel index space for boxes. Throws what read_volume throws for a file it cannot read
// (InputError or OptionError, one line naming the file); read() throws InputError naming the box
// when the file no longer holds it (truncated since it was opened) or a float sample in it is NaN
// or infinite, and std::invalid_argument for a box outside the volume.
#pragma once
#include <cstdint>
#include <memory>
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

// Slabs of whole slices of a volume whose samples are one compressed stream — NRRD with gzip or
// bzip2 encoding in one data file (any byte skip ≥ 0, no line skip), .nii.gz (or .hdr with .img.gz),
// MetaImage with CompressedData in one file — inflated once, front to back, never whole; or a
// DICOM series of one slice per file, whose files are read as their slices are held (a multi-frame
// file is not a stream: read it whole). hold(z0, z1) keeps slices z0..z1 (dropping the others; in a
// stream, a z0 before the slices held inflates it again from its start); read(box) gives a box within the slices held exactly
// as read_volume(path) holds it (the same bytes, scaling and origin as VolumeRegions::read), from
// any thread between holds. Memory: the slices held, and zlib's state.
//
// Throws what read_volume throws for a file it cannot read; hold() throws InputError naming the
// file and the slice when the stream is cut short or corrupt before it, or, holding the last
// slice, when the stream does not end with its check value (gzip's CRC-32) where read_volume would
// refuse it; std::invalid_argument for slices outside the volume. read() throws
// std::invalid_argument for a box outside the slices held, and InputError for a NaN or infinite
// float sample. Other files give nullopt (see open_regions).
class VolumeStream {
public:
  VolumeStream(VolumeStream&&) noexcept;
  VolumeStream& operator=(VolumeStream&&) noexcept;
  ~VolumeStream();
  const Volume& header() const;  // dims, type, spacing, origin, direction; no samples
  void hold(std::int64_t z0, std::int64_t z1);
  Volume read(const VoxelBox& box) const;
  std::uint64_t inflations() const;  // how many times the stream was inflated from its start
  bool slice_files() const;          // a DICOM series: its slices are read from their files

  struct State;

private:
  explicit VolumeStream(std::unique_ptr<State> s);
  std::unique_ptr<State> s_;
  friend std::optional<VolumeStream> open_stream(const std::string& path, const ReadOptions& options);
};

std::optional<VolumeStream> open_stream(const std::string& path, const ReadOptions& options = {});

// A file's boxes by the cheapest route its format allows: by seeking (open_regions), slab by slab
// (open_stream), else from the whole volume, read once (read_volume). What a process that computes
// only some bricks reads them with (the MPI ranks other than 0, Python's ranks given a path).
// read(box) gives the box as VolumeRegions::read does; with a stream (streams()), hold() the slices
// first, front to back. Throws what open_regions, open_stream and read_volume throw.
class RegionReader {
public:
  explicit RegionReader(const std::string& path, const ReadOptions& options = {});
  const Volume& header() const;  // dims, type, geometry (the whole volume's samples only on the "whole volume" route)
  Volume read(const VoxelBox& box) const;
  bool streams() const { return stream_.has_value(); }
  void hold(std::int64_t z0, std::int64_t z1);  // a stream's slices z0..z1; nothing on the other routes
  // "regions", "slabs of the stream", "slabs of the slice files" or "whole volume" (--json's "ranks_read").
  const char* route() const;
  // The route a reader of `path` would take, from the file's headers alone.
  static const char* route_of(const std::string& path, const ReadOptions& options = {});

private:
  std::optional<VolumeRegions> regions_;
  std::optional<VolumeStream> stream_;
  std::optional<Volume> whole_;
};

}  // namespace adaptiso
