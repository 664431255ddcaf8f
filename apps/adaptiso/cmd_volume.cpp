// adaptiso info / adaptiso generate.
#include <fmt/format.h>

#include <iostream>

#include "adaptiso/synthetic.hpp"
#include "cli_common.hpp"

namespace adaptiso::cli {

void add_info(CLI::App& app) {
  auto* cmd = app.add_subcommand("info", "Dimensions, spacing, type, value range and a coarse histogram of a volume");
  auto in = std::make_shared<VolumeInput>();
  auto out = std::make_shared<OutputFlags>();
  auto bins = std::make_shared<int>(16);
  in->add(cmd);
  out->add(cmd);
  cmd->add_option("--bins", *bins, "Histogram bins")->check(CLI::Range(1, 4096));
  cmd->callback([=] {
    auto t0 = Clock::now();
    Volume v = in->load();
    double load_s = seconds_since(t0);
    const ValueRange range = value_range(v);
    auto h = histogram(v, range, *bins);
    auto j = volume_json(v, range);
    j["file"] = in->path;
    j["histogram"] = {{"min", h.min}, {"max", h.max}, {"counts", h.counts}};
    j["seconds"] = load_s;
    if (out->json) return print_json(j);
    std::cout << fmt::format("{}\n  dims     {} x {} x {} ({} voxels)\n  type     {}\n  spacing  {} {} {}\n  origin   {} {} {}\n", in->path,
                             v.dims[0], v.dims[1], v.dims[2], v.voxel_count(), scalar_name(v.type), v.spacing[0], v.spacing[1],
                             v.spacing[2], v.origin[0], v.origin[1], v.origin[2]);
    if (v.is_oblique())
      std::cout << fmt::format("  direction [{:.4f} {:.4f} {:.4f}; {:.4f} {:.4f} {:.4f}; {:.4f} {:.4f} {:.4f}] (oblique, kept as stored)\n",
                               v.direction[0], v.direction[1], v.direction[2], v.direction[3], v.direction[4], v.direction[5],
                               v.direction[6], v.direction[7], v.direction[8]);
    std::cout << fmt::format("  range    {} .. {}\n  histogram:\n", h.min, h.max);
    std::uint64_t peak = 1;
    for (auto c : h.counts) peak = std::max(peak, c);
    const double w = (h.max - h.min) / static_cast<double>(h.counts.size());
    for (std::size_t b = 0; b < h.counts.size(); ++b)
      std::cout << fmt::format(
          "    [{:>12.6g}, {:>12.6g}) {:>12} {}\n", h.min + b * w, h.min + (b + 1) * w, h.counts[b],
          std::string(static_cast<std::size_t>(40.0 * static_cast<double>(h.counts[b]) / static_cast<double>(peak)), '#'));
    std::cout << fmt::format("  read in {:.3f} s\n", load_s);
  });
}

void add_generate(CLI::App& app) {
  auto* cmd = app.add_subcommand("generate", "Write a built-in volume (sphere, marschner-lobb, linear, noise, torus) as NRRD");
  auto name = std::make_shared<std::string>();
  auto size = std::make_shared<std::int64_t>(50);
  auto type = std::make_shared<std::string>();
  auto output = std::make_shared<std::string>();
  auto out = std::make_shared<OutputFlags>();
  cmd->add_option("NAME", *name, "sphere | marschner-lobb | linear | noise | torus")->required();
  cmd->add_option("--size", *size, "Edge length N of the N³ volume")->default_val(50);
  cmd->add_option("--type", *type, "Element type (default: int16 for sphere, float32 otherwise)");
  cmd->add_option("-o,--output", *output, "Output .nrrd")->required();
  out->add(cmd);
  cmd->callback([=] {
    ScalarType t = synthetic_default_type(*name);
    if (!type->empty()) {
      auto p = parse_scalar_type(*type);
      if (!p) throw InputError(fmt::format("--type: unknown type '{}'", *type));
      t = *p;
    }
    Volume v = make_synthetic(*name, *size, t);
    write_nrrd(v, *output);
    auto j = volume_json(v, value_range(v));
    j["output"] = *output;
    if (out->json)
      print_json(j);
    else if (!out->quiet)
      std::cout << fmt::format("wrote {} ({}³ {})\n", *output, *size, scalar_name(t));
  });
}

}  // namespace adaptiso::cli
