// Command-line options shared by several commands: the reduction (reduce, prepare, run, view) and
// the rest of the preparation (prepare, run, view). They fill the library's option structs.
#pragma once
#include <CLI/CLI.hpp>

#include "adaptiso/prepare.hpp"
#include "adaptiso/reduce.hpp"

namespace adaptiso::cli {

struct ReduceFlags {
  std::string method = "reconstruction";
  std::string gradient = "central";
  ReduceOptions o;
  CLI::Option* max_error = nullptr;
  // The options of the paper's reduction, which only the Delaunay grid uses (prepare, run, view
  // refuse them with the bisection grid rather than ignore them).
  std::vector<CLI::Option*> delaunay_only;
  void add(CLI::App* app);
  ReduceOptions options() const;
};

struct PrepareFlags {
  ReduceFlags reduce;
  std::string grid = "bisection";
  double max_displacement = 0;
  bool verify = false;
  std::string gradients = "auto";
  bool sequential_delaunay = false;
  CLI::Option* sequential = nullptr;
  std::uint32_t tree_depth = kDefaultTreeDepth;
  void add(CLI::App* app);
  PrepareOptions options(const std::string& source_path) const;
};

}  // namespace adaptiso::cli
