// Shared pieces of the adaptiso command line: volume-input options (raw), output options
// (--json, --quiet), the terminal progress line, and the exit-code contract:
// 0 success, 2 bad usage or unreadable input, 1 internal failure.
#pragma once
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <chrono>
#include <string>

#include "adaptiso/number.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/progress.hpp"
#include "adaptiso/volume_io.hpp"

namespace adaptiso::cli {

// The refusal of every finite-number check below.
inline std::string not_finite(const std::string& s) { return "'" + s + "' is not a finite number"; }
// For every floating-point option: CLI11 would take "nan" and "inf" as numbers. Subnormals such
// as 1e-320 are finite and pass.
inline CLI::Validator finite_number() {
  return CLI::Validator([](std::string& s) -> std::string { return parse_finite(s) ? "" : not_finite(s); }, "FINITE");
}
// A finite number ≥ 0 (> 0 with `positive`), refused in one short line: CLI11's NonNegativeNumber
// and PositiveNumber print their range's upper end, the largest double, in all its 309 digits,
// and combined with finite_number() both messages.
inline CLI::Validator finite_sign(bool positive) {
  return CLI::Validator(
      [positive](std::string& s) -> std::string {
        const auto x = parse_finite(s);
        if (!x) return not_finite(s);
        if (positive ? *x > 0 : *x >= 0) return "";
        return (positive ? "must be positive, got " : "must not be negative, got ") + s;
      },
      positive ? "POSITIVE" : "NON-NEGATIVE");
}
inline CLI::Validator non_negative_number() { return finite_sign(false); }
inline CLI::Validator positive_number() { return finite_sign(true); }

struct VolumeInput {
  std::string path;
  std::string dims, type, endian = "little", spacing;
  std::uint64_t header_bytes = 0;
  void add(CLI::App* app);
  ReadOptions read_options() const;  // throws InputError for bad --dims/--type/--spacing
  Volume load() const;               // throws InputError
};

struct OutputFlags {
  bool json = false;
  bool quiet = false;
  void add(CLI::App* app);
};

// A progress line on stderr, shown only on a terminal, without --quiet or --json, and only once a
// stage has run for more than a second.
class TerminalProgress {
public:
  explicit TerminalProgress(bool enabled);
  ~TerminalProgress();
  Progress callback();
  void finish();

private:
  bool enabled_;
  bool drawn_ = false;
  std::chrono::steady_clock::time_point start_;
  std::string last_stage_;
  int last_percent_ = -1;
};

// Refuses (InputError naming `option`) an output that is the input itself, or another output:
// the atomic write would replace the file being read, or one output the other. The files are
// compared when both exist (links followed), their absolute paths otherwise.
void refuse_same_file(const std::string& input, const std::string& output, const std::string& option);

void print_json(const nlohmann::json& j);
double seconds_since(std::chrono::steady_clock::time_point t0);
// "error ≤ B guaranteed (asked E)" for a bisection grid, the measured piecewise-linear error
// against the bound for a Delaunay grid.
std::string error_summary(const PrepareStats& stats);
nlohmann::json volume_json(const Volume& v, const ValueRange& range);

// Parses "--iso" values (comma-separated numbers); relative ones map [0,1] onto the value range
// of `source` (volume.hpp: from_fraction; `source` is named when the scaled value overflows).
std::vector<double> parse_iso_values(const std::vector<std::string>& tokens, bool relative, const ValueRange& range,
                                     const std::string& source);

// A size in bytes: digits with at most one decimal point, then an optional unit (k, M, G, T: powers
// of 1024, with or without "iB"; "B": bytes). No signs, exponents or hex. OptionError(option) else.
std::uint64_t parse_byte_size(const std::string& text, const std::string& option);
// --memory-limit (adaptiso/memory.hpp): set as the options are parsed, before the command runs.
void add_memory_limit(CLI::App* cmd);

// The command-line flag of a library option named in an OptionError ("max_error" → "--max-error").
std::string flag_for(const std::string& option);

using Clock = std::chrono::steady_clock;

// Command registration; each returns the callback run when the subcommand was chosen.
void add_info(CLI::App& app);
void add_generate(CLI::App& app);
void add_reduce(CLI::App& app);
void add_prepare(CLI::App& app);
void add_export(CLI::App& app);
void add_extract(CLI::App& app);
void add_run(CLI::App& app);
void add_mc(CLI::App& app);
void add_view(CLI::App& app);
void add_compare(CLI::App& app);

}  // namespace adaptiso::cli
