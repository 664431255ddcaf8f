// Reduction options shared by reduce, prepare, run and view.
#pragma once
#include <CLI/CLI.hpp>

#include "adaptiso/reduce.hpp"

namespace adaptiso::cli {

struct ReduceFlags {
  std::string method = "reconstruction";
  std::string gradient = "central";
  ReduceOptions o;
  void add(CLI::App* app, double default_error = 0.0) {
    o.max_error = default_error;
    app->add_option("--method", method, "reconstruction | structural | both")
        ->check(CLI::IsMember({"reconstruction", "structural", "both"}));
    app->add_option("--max-error", o.max_error, "Reconstruction: max-norm error bound (data units; fraction of the range with --relative)");
    app->add_option("--threshold", o.threshold, "Structural: gradient magnitude threshold (data units per voxel; fraction of the largest with --relative)");
    app->add_option("--gradient", gradient, "Structural: central | canny")->check(CLI::IsMember({"central", "canny"}));
    app->add_option("--sigma", o.sigma, "Canny: Gaussian sigma in voxels");
    app->add_option("--kernel", o.kernel, "Canny: kernel size (odd; default 2*ceil(3 sigma)+1)");
    app->add_flag("--relative", o.relative, "Error and iso-values as fractions of the value range, threshold of the largest gradient");
  }
  ReduceOptions options() const {
    ReduceOptions r = o;
    r.method = method == "structural" ? ReduceMethod::structural : method == "both" ? ReduceMethod::both : ReduceMethod::reconstruction;
    r.gradient = gradient == "canny" ? GradientOperator::canny : GradientOperator::central;
    return r;
  }
};

}  // namespace adaptiso::cli
