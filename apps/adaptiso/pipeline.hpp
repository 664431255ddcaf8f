// The preprocessing pipeline shared by prepare, run and view: reduce → tetrahedralize →
// gradients → reconstruction error → extraction index, with timings per stage as JSON.
#pragma once
#include <nlohmann/json.hpp>

#include "adaptiso/interval_tree.hpp"
#include "adaptiso/progress.hpp"
#include "adaptiso/tet_grid.hpp"
#include "reduce_options.hpp"

namespace adaptiso::cli {

struct PipelineFlags {
  bool sequential_delaunay = false;
  std::uint32_t tree_depth = kDefaultTreeDepth;
  void add(CLI::App* app);
};

struct Prepared {
  TetGrid grid;
  IntervalTree index;
  nlohmann::json stats;  // voxels, kept, ratio, tetrahedra, max_error, pl_max_error, pl_rms_error, seconds{...}
};

Prepared prepare_grid(const Volume& v, const std::string& source_path, const ReduceFlags& rf, const PipelineFlags& pf,
                      const Progress& progress);

// Parses "--iso" values (comma-separated numbers); relative ones map [0,1] onto [min, max].
std::vector<double> parse_iso_values(const std::vector<std::string>& tokens, bool relative, double min, double max);

}  // namespace adaptiso::cli
