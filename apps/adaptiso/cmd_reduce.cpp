// adaptiso reduce: vertex reduction only, kept vertices as a PLY point cloud.
#include <fmt/format.h>

#include <iostream>

#include "adaptiso/point_cloud.hpp"
#include "cli_common.hpp"
#include "options.hpp"

namespace adaptiso::cli {

void add_reduce(CLI::App& app) {
  auto* cmd = app.add_subcommand("reduce", "Vertex reduction (paper §2.1): write the kept vertices as a PLY point cloud");
  auto in = std::make_shared<VolumeInput>();
  auto rf = std::make_shared<ReduceFlags>();
  auto out = std::make_shared<OutputFlags>();
  auto output = std::make_shared<std::string>();
  auto verify = std::make_shared<bool>(false);
  in->add(cmd);
  rf->add(cmd);
  out->add(cmd);
  add_memory_limit(cmd);
  cmd->add_option("-o,--output", *output, "Kept vertices (.ply)")->required();
  cmd->add_flag("--verify", *verify, "Check the error bound voxel by voxel and report the largest error found");
  cmd->callback([=] {
    Volume v = in->load();
    TerminalProgress tp(!out->quiet && !out->json);
    auto t0 = Clock::now();
    ReduceOptions o = rf->options();
    const ValueRange range = value_range(v);
    if (rf->max_error->count() == 0) o.max_error = default_max_error(range, o.relative);  // as prepare, run and view
    ReduceResult r = reduce(v, range, o, tp.callback());
    double secs = seconds_since(t0);
    tp.finish();
    nlohmann::json j = {{"voxels", v.voxel_count()},
                        {"kept", r.kept.size()},
                        {"ratio", static_cast<double>(r.kept.size()) / static_cast<double>(v.voxel_count())},
                        {"method", rf->method},
                        {"max_error", r.max_error},
                        {"seconds", secs},
                        {"voxels_per_second", static_cast<double>(v.voxel_count()) / std::max(secs, 1e-9)}};
    if (o.method != ReduceMethod::reconstruction) j["threshold"] = r.threshold;
    if (o.method == ReduceMethod::both) {
      j["kept_reconstruction"] = r.kept_reconstruction;
      j["kept_structural"] = r.kept_structural;
    }
    if (*verify) {
      if (o.method == ReduceMethod::structural)
        throw InputError("--verify checks the reconstruction error bound; use --method reconstruction or both");
      double e = verify_reconstruction(v, r);
      j["max_error_found"] = e;
      if (e > r.max_error + error_tolerance(range, r.max_error))
        throw std::runtime_error(fmt::format("verification failed: error {} exceeds the bound {}", e, r.max_error));
    }
    write_points_ply(*output, v, r.kept);
    if (out->json) return print_json(j);
    if (out->quiet) return;
    std::cout << fmt::format("kept {} of {} voxels ({:.4f} %), method {}, {:.3f} s ({:.1f} M voxels/s)\n", r.kept.size(), v.voxel_count(),
                             100.0 * j["ratio"].get<double>(), rf->method, secs, j["voxels_per_second"].get<double>() / 1e6);
    if (*verify) std::cout << fmt::format("verified: largest error {} (bound {})\n", j["max_error_found"].get<double>(), r.max_error);
    std::cout << "wrote " << *output << "\n";
  });
}

}  // namespace adaptiso::cli
