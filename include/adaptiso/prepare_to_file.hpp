// adaptiso/prepare_to_file.hpp — preparation straight into a grid file: prepare (prepare.hpp) and
// save_grid (grid_file.hpp) in one, the file written as the grid is made.
#pragma once
#include <string>

#include "adaptiso/prepare.hpp"

namespace adaptiso {

// prepare(std::move(v), ...) and save_grid(grid, path) in one, for a caller that wants the file:
// the same bytes, written as they are made. The grid's positions and gradients are on disk and
// freed before the index is built, and the index's sort takes what the file's bytes plus 2.5
// volumes leave, so the peak stays there where the grid and its index in memory at once cannot
// (the 256×256×133 chest CT: 304 MB file, 2.5 volumes 22 MB). Returns the statistics, with the
// writing's time as the stage "save". Throws what prepare and save_grid throw; on any failure no
// file is left at path.
PrepareStats prepare_to_file(Volume&& v, const PrepareOptions& options, const std::string& path, const Progress& progress = {});
PrepareStats prepare_to_file(Volume&& v, const ValueRange& range, const PrepareOptions& options, const std::string& path,
                             const Progress& progress = {});
// The same, lending the volume (it keeps its voxels, which then stay resident: the Python module).
PrepareStats prepare_to_file(const Volume& v, const PrepareOptions& options, const std::string& path, const Progress& progress = {});

}  // namespace adaptiso
