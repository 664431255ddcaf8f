#include "options.hpp"

#include "cli_common.hpp"

#include <fmt/format.h>

namespace adaptiso::cli {

void ReduceFlags::add(CLI::App* app) {
  const std::string max_error_help = fmt::format(
      "Max-norm error bound (data units; fraction of the range with --relative); default: {:g} of the value range", kDefaultRelativeError);
  delaunay_only.push_back(app->add_option("--method", method, "Delaunay grid (and reduce): reconstruction | structural | both")
                              ->check(CLI::IsMember({"reconstruction", "structural", "both"})));
  max_error = app->add_option("--max-error", o.max_error, max_error_help)->check(finite_number());
  delaunay_only.push_back(
      app->add_option("--threshold", o.threshold,
                      "Structural: gradient magnitude threshold (data units per voxel; fraction of the largest with --relative)")
          ->check(finite_number()));
  delaunay_only.push_back(
      app->add_option("--gradient", gradient, "Structural: central | canny")->check(CLI::IsMember({"central", "canny"})));
  delaunay_only.push_back(app->add_option("--sigma", o.sigma, "Canny: Gaussian sigma in voxels")->check(finite_number()));
  delaunay_only.push_back(app->add_option("--kernel", o.kernel, "Canny: kernel size (odd; default 2*ceil(3 sigma)+1)"));
  app->add_flag("--relative", o.relative, "Error and iso-values as fractions of the value range, threshold of the largest gradient");
}

ReduceOptions ReduceFlags::options() const {
  ReduceOptions r = o;
  r.method = method == "structural" ? ReduceMethod::structural : method == "both" ? ReduceMethod::both : ReduceMethod::reconstruction;
  r.gradient = gradient == "canny" ? GradientOperator::canny : GradientOperator::central;
  return r;
}

void PrepareFlags::add(CLI::App* app) {
  app->add_option("--grid", grid,
                  "bisection: longest-edge bisection on the voxel lattice, error guaranteed (default) | delaunay: the paper's "
                  "reduction + Delaunay")
      ->check(CLI::IsMember({"bisection", "delaunay"}));
  reduce.add(app);
  app->add_option("--max-displacement", max_displacement,
                  "Bisection: also bound how far, to first order, an iso-surface may move (voxels; 0: off)")
      ->check(finite_number());
  app->add_flag("--verify", verify, "Bisection: measure the reconstruction error voxel by voxel and check the guarantee");
  app->add_option("--gradients", gradients, "Vertex gradients: auto | lsq (least squares, the paper's) | central (central differences)")
      ->check(CLI::IsMember({"auto", "lsq", "central"}));
  app->add_option("--tree-depth", tree_depth, "Depth of the interval tree used for extraction")
      ->capture_default_str()
      ->check(CLI::Range(0, 24));
  sequential =
      app->add_flag("--sequential-delaunay", sequential_delaunay, "Use CGAL's sequential triangulation (the parallel one is the default)");
}

PrepareOptions PrepareFlags::options(const std::string& source_path) const {
  if (grid == "bisection") {
    std::vector<CLI::Option*> given = reduce.delaunay_only;
    given.push_back(sequential);
    for (const CLI::Option* opt : given)
      if (opt && opt->count() > 0)
        throw InputError(
            fmt::format("{} is an option of the Delaunay grid (the paper's reduction); the bisection grid does not use it (add "
                        "--grid delaunay, or leave it out)",
                        opt->get_name()));
  }
  PrepareOptions p;
  p.reduce = reduce.options();
  if (reduce.max_error->count() > 0) p.max_error = p.reduce.max_error;  // otherwise the library's default
  p.relative = p.reduce.relative;
  p.gradients = gradients == "lsq"       ? GradientMethod::least_squares
                : gradients == "central" ? GradientMethod::central
                                         : GradientMethod::automatic;
  p.parallel_delaunay = !sequential_delaunay;
  p.tree_depth = tree_depth;
  p.grid = grid == "delaunay" ? GridKind::delaunay : GridKind::bisection;
  p.max_displacement = max_displacement;
  p.verify = verify;
  p.source_name = source_path;
  return p;
}

}  // namespace adaptiso::cli
