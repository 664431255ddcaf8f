// The grid file loader against files that lie (.adg). fuzz_grid's byte mutations almost never get
// past the checksum; here a custom mutator takes a grid file apart into its sections
// (io/grid_file_sections.hpp), changes one as a hostile or careless writer would (a structural or
// data lie of GridSections' mutate_sections, or libFuzzer's own mutation of one section's bytes),
// and puts the file back with its counts and checksum made to match, so every mutation reaches the
// loader's checks of what the file says. A grid that loads is then used as a user's would be: its
// surfaces from its tetrahedra, from the hierarchy at coarser errors (the walk that trusts the
// vertex numbering) and a coarser grid from it (bisection_coarsen); an over-read there is a finding.
// The seeds are grid files adaptiso wrote (scripts/fuzz.sh).
#include <algorithm>
#include <cstring>
#include <memory>
#include <random>

#include "adaptiso/bisection.hpp"
#include "adaptiso/extractor.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "fuzz_util.hpp"
#include "io/grid_file_sections.hpp"

using adaptiso::detail::GridSections;

extern "C" std::size_t LLVMFuzzerMutate(std::uint8_t* data, std::size_t size, std::size_t max_size);

extern "C" std::size_t LLVMFuzzerCustomMutator(std::uint8_t* data, std::size_t size, std::size_t max_size, unsigned int seed) {
  auto s = GridSections::parse({reinterpret_cast<const char*>(data), size});
  if (!s) return LLVMFuzzerMutate(data, size, max_size);  // not a grid file any more: plain bytes
  std::mt19937_64 rng(seed);
  for (int n = 1 + static_cast<int>(rng() % 2); n > 0; --n) {
    std::string* parts[] = {&s->meta, &s->ijk, &s->values, &s->tets, &s->nodes, &s->by_min, &s->hierarchy_head, &s->error_codes, &s->spans};
    std::string& part = *parts[rng() % std::size(parts)];
    if (rng() % 3 == 0 && !part.empty()) {
      // libFuzzer's own mutation (coverage-guided, with its dictionary of compared values) of one
      // section's bytes, the section growing or shrinking by what it returns.
      std::string buffer = part;
      buffer.resize(part.size() + 64);
      const std::size_t n_out = LLVMFuzzerMutate(reinterpret_cast<std::uint8_t*>(buffer.data()), part.size(), buffer.size());
      buffer.resize(n_out);
      part = std::move(buffer);
    } else {
      adaptiso::detail::mutate_sections(*s, rng, true);
    }
  }
  const std::string out = s->assemble();
  if (out.size() > max_size) return size;  // unchanged: the mutation made it too large
  std::memcpy(data, out.data(), out.size());
  return out.size();
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string path = fuzz::write("g.adg", fuzz::as_view(data, size));
  // The distance query's own load, the hierarchy alone: the tetrahedra and the index are skipped,
  // not checked, so a file lying only there loads here and must still walk safely.
  std::shared_ptr<const adaptiso::PreparedGrid> parts;
  fuzz::expect_input_error_or_success(
      [&] { parts = std::make_shared<const adaptiso::PreparedGrid>(adaptiso::load_grid(path, adaptiso::GridParts::hierarchy)); });
  if (parts && parts->grid.vertex_count() <= 100000) {
    const auto& s = parts->grid.source;
    fuzz::expect_input_error_or_success([&] {
      const adaptiso::HierarchyQuery query(parts);
      for (double f : {0.3, 0.61}) {
        query.extract_within(s.min + f * (s.max - s.min), 0.5);
        query.extract_within(s.min + f * (s.max - s.min), 2.0, nullptr, 1);
      }
    });
  }
  std::shared_ptr<const adaptiso::PreparedGrid> grid;
  fuzz::expect_input_error_or_success([&] { grid = std::make_shared<const adaptiso::PreparedGrid>(adaptiso::load_grid(path)); });
  if (!grid || grid->grid.vertex_count() > 100000) return 0;
  const auto& src = grid->grid.source;
  const double isos[] = {src.min + 0.3 * (src.max - src.min), src.min + 0.61 * (src.max - src.min), src.max};
  fuzz::expect_input_error_or_success([&] {
    adaptiso::Extractor ex(grid);
    for (double iso : isos) ex.extract(iso);
  });
  if (!grid->hierarchy) return 0;
  fuzz::expect_input_error_or_success([&] {
    const adaptiso::HierarchyQuery query(grid);
    const double e = query.prepared_error();
    for (double iso : isos) {
      query.extract(iso, e, 0);
      query.extract(iso, 4 * e + 1e-9 * (src.max - src.min), 0);
      if (!grid->hierarchy->displacement_code.empty()) query.extract(iso, e, 2.0);
    }
  });
  fuzz::expect_input_error_or_success([&] {
    adaptiso::BisectionOptions o;
    o.max_error = 8 * grid->hierarchy->codes.error(grid->hierarchy->error_threshold);
    adaptiso::bisection_coarsen(grid->grid, *grid->hierarchy, o);
    o.cell_floor = 1;
    adaptiso::bisection_coarsen(grid->grid, *grid->hierarchy, o);
  });
  return 0;
}
