// adaptiso/prepare_to_file.hpp — preparation straight into a grid file: prepare (prepare.hpp) and
// save_grid (grid_file.hpp) in one, without the index.
#pragma once
#include <string>

#include "adaptiso/prepare.hpp"

namespace adaptiso {

// prepare(std::move(v), ...) and save_grid(grid, path) in one, for a caller that wants the file,
// without building the index: the file leaves it out (loading builds it at options.tree_depth,
// grid_file.hpp), so the index's time and memory are not spent here (the CT bunny: 2.2-2.8 s of its
// 8.5-9.8 s on 2 cores). A bisection grid's tetrahedra go into the file as the selection makes
// them (BisectionOptions::sink), unless options.verify or least-squares gradients need them
// afterwards: the bunny's peak 0.83 GB instead of 1.46. The volume's voxels go once the gradients
// are made. Returns the statistics, with the writing's time as the stage "save" (the selection's
// "select" and "gradients" then leave out what ran inside them for the file). Throws what prepare
// and save_grid throw; on any failure no file is left at path.
PrepareStats prepare_to_file(Volume&& v, const PrepareOptions& options, const std::string& path, const Progress& progress = {});
PrepareStats prepare_to_file(Volume&& v, const ValueRange& range, const PrepareOptions& options, const std::string& path,
                             const Progress& progress = {});
// The same, lending the volume (it keeps its voxels, which then stay resident: the Python module).
PrepareStats prepare_to_file(const Volume& v, const PrepareOptions& options, const std::string& path, const Progress& progress = {});

}  // namespace adaptiso
