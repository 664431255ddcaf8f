#include "cli_common.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <mutex>

#include "adaptiso/memory.hpp"
#include "adaptiso/number.hpp"

namespace adaptiso::cli {

void VolumeInput::add(CLI::App* app) {
  app->add_option("VOLUME", path, "Volume file (.nrrd .nhdr .nii[.gz] .mha .mhd .vti .vtk), DICOM folder, or raw file")->required();
  auto* g = app->add_option_group("raw input", "For headerless raw files");
  g->add_option("--dims", dims, "Raw: dimensions X,Y,Z");
  g->add_option("--type", type, "Raw: uint8 int8 uint16 int16 uint32 int32 float32 float64");
  g->add_option("--endian", endian, "Raw: little or big")->check(CLI::IsMember({"little", "big"}));
  g->add_option("--spacing", spacing, "Raw: spacing X,Y,Z");
  g->add_option("--header-bytes", header_bytes, "Raw: bytes to skip at the start of the file");
}

ReadOptions VolumeInput::read_options() const {
  ReadOptions o;
  if (!dims.empty() || !type.empty()) {
    if (dims.empty() || type.empty()) throw InputError(fmt::format("{}: raw input needs both --dims and --type", path));
    RawOptions r;
    auto d = parse_number_list(dims, 3, "--dims");
    for (int a = 0; a < 3; ++a) {
      if (d[a] < 1 || d[a] != static_cast<double>(static_cast<std::int64_t>(d[a])))
        throw InputError(fmt::format("--dims: {} is not a positive whole number", d[a]));
      r.dims[a] = static_cast<std::int64_t>(d[a]);
    }
    auto t = parse_scalar_type(type);
    if (!t) throw InputError(fmt::format("--type: unknown type '{}'", type));
    r.type = *t;
    r.big_endian = endian == "big";
    if (!spacing.empty()) {
      auto s = parse_number_list(spacing, 3, "--spacing");
      r.spacing = {s[0], s[1], s[2]};
    }
    r.header_bytes = header_bytes;
    o.raw = r;
  }
  return o;
}

Volume VolumeInput::load() const { return read_volume(path, read_options()); }

void OutputFlags::add(CLI::App* app) {
  app->add_flag("--json", json, "Print the statistics as one JSON object on stdout");
  app->add_flag("--quiet,-q", quiet, "No progress output");
}

TerminalProgress::TerminalProgress(bool enabled) : enabled_(enabled && isatty(STDERR_FILENO)), start_(Clock::now()) {}
TerminalProgress::~TerminalProgress() { finish(); }

Progress TerminalProgress::callback() {
  if (!enabled_) return {};
  auto mtx = std::make_shared<std::mutex>();
  return [this, mtx](std::string_view stage, double f) {
    std::lock_guard lock(*mtx);
    if (stage != last_stage_) {
      last_stage_ = std::string(stage);
      last_percent_ = -1;
    }
    int pct = static_cast<int>(f * 100);
    if (pct == last_percent_ || seconds_since(start_) < 1.0) return;
    last_percent_ = pct;
    std::fprintf(stderr, "\r\033[K%s %3d%%", last_stage_.c_str(), pct);
    std::fflush(stderr);
    drawn_ = true;
  };
}

void TerminalProgress::finish() {
  if (drawn_) {
    std::fprintf(stderr, "\r\033[K");
    std::fflush(stderr);
    drawn_ = false;
  }
}

void refuse_same_file(const std::string& input, const std::string& output, const std::string& option) {
  namespace fs = std::filesystem;
  std::error_code ec, ec_in, ec_out;
  bool same = fs::equivalent(input, output, ec);
  if (ec) same = fs::weakly_canonical(input, ec_in) == fs::weakly_canonical(output, ec_out) && !ec_in && !ec_out;
  if (same) throw InputError(fmt::format("{} {}: is {} itself; writing it would replace what it is made from", option, output, input));
}

void print_json(const nlohmann::json& j) { std::cout << j.dump(2) << std::endl; }

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

std::string error_summary(const PrepareStats& s) {
  std::string text = s.error_bound >= 0 ? fmt::format("error <= {:.6g} guaranteed (asked {:.6g})", s.error_bound, s.max_error)
                                        : fmt::format("octree error bound {:.6g}", s.max_error);
  if (s.pl_max_error >= 0) text += fmt::format("; piecewise-linear error measured: max {:.6g}, rms {:.6g}", s.pl_max_error, s.pl_rms_error);
  return text;
}

nlohmann::json volume_json(const Volume& v, const ValueRange& r) {
  return {{"dims", v.dims},
          {"spacing", v.spacing},
          {"origin", v.origin},
          {"direction", v.direction},
          {"type", std::string(scalar_name(v.type))},
          {"min", r.min},
          {"max", r.max},
          {"voxels", v.voxel_count()},
          {"bytes", v.bytes.size()}};
}

std::vector<double> parse_iso_values(const std::vector<std::string>& tokens, bool relative, const ValueRange& range,
                                     const std::string& source) {
  std::vector<double> out;
  for (const auto& s : tokens) {
    auto x = parse_finite(s);
    if (!x) throw InputError(fmt::format("--iso: '{}' is not a finite number", s.substr(0, 40)));
    out.push_back(relative ? from_fraction(range, *x, FractionOf::value, fmt::format("{}: --iso {} with --relative", source, s)) : *x);
  }
  if (out.empty()) throw InputError("--iso: give at least one iso-value");
  return out;
}

std::string flag_for(const std::string& option) {
  if (option == "web_dir") return "--web";
  if (option == "structural_gradient") return "--gradient";
  std::string flag = "--" + option;
  std::replace(flag.begin(), flag.end(), '_', '-');
  return flag;
}

std::uint64_t parse_byte_size(const std::string& text, const std::string& option) {
  const std::string refusal = fmt::format("'{}' is not a size in bytes (e.g. 4000000000, 4G, 512M)", text.substr(0, 40));
  std::size_t used = 0, points = 0;
  while (used < text.size() && (std::isdigit(static_cast<unsigned char>(text[used])) || text[used] == '.')) points += text[used++] == '.';
  if (used == 0 || points > 1 || text[0] == '.' || text[used - 1] == '.') throw OptionError(option, refusal);
  std::string unit = text.substr(used);
  for (auto& c : unit) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  double scale = 1;
  if (!unit.empty() && unit != "B") {
    const auto p = std::string("KMGT").find(unit[0]);
    const std::string rest = unit.substr(1);
    if (p == std::string::npos || !(rest.empty() || rest == "B" || rest == "IB")) throw OptionError(option, refusal);
    scale = std::pow(1024.0, static_cast<double>(p + 1));
  }
  const double bytes = std::round(std::stod(text.substr(0, used)) * scale);
  if (bytes >= 18446744073709551616.0) throw OptionError(option, fmt::format("'{}' is more than 2^64 bytes", text.substr(0, 40)));
  if (bytes < 1) throw OptionError(option, "must be at least 1 byte");
  return static_cast<std::uint64_t>(bytes);
}

void add_memory_limit(CLI::App* cmd) {
  cmd->add_option_function<std::string>(
         "--memory-limit", [](const std::string& text) { set_memory_limit(parse_byte_size(text, "memory_limit")); },
         "The most memory this command may hold, in bytes (8000000000, 8G, 512M): work whose estimate does not fit is refused "
         "before it starts (default: what the machine has free)")
      ->type_name("BYTES");
}

}  // namespace adaptiso::cli
