// A grid file (.adg, versions 2 to 6; grid_file.hpp) taken apart into its sections and put back
// together with its counts and checksum made to match. For the structure-aware fuzz target
// (fuzz/fuzz_grid_structure.cpp) and the tests that build lying grid files: a mutation of a
// section survives the checksum and reaches the loader's checks of what the file says. Header-only;
// no part of the library.
#pragma once
#include <zlib.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <numeric>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace adaptiso::detail {

struct GridSections {
  std::uint32_t version = 6, flags = 0, depth = 0, reserved = 0;
  std::string meta;                             // JSON
  std::string ijk, values, gradients, tets;     // 12, 8, 12 and 16 bytes a record
  std::string nodes, by_min, by_max;            // index: 24 bytes a node, 4 an entry
  std::string hierarchy_head;                   // 40 bytes
  std::string error_codes, displacement_codes;  // a byte a vertex
  std::string spans;                            // 8 bytes a vertex

  static constexpr std::uint32_t kHasIndex = 1, kHasHierarchy = 2, kHasDisplacement = 4;

  std::uint64_t vertices() const { return ijk.size() / 12; }
  std::uint64_t tetrahedra() const { return tets.size() / 16; }

  // The sections of a well-formed file whose counts add up to its size (the checksum is not
  // checked); nothing for anything else.
  static std::optional<GridSections> parse(std::string_view f) {
    auto u32 = [&](std::size_t at) {
      std::uint32_t x;
      std::memcpy(&x, f.data() + at, 4);
      return x;
    };
    auto u64 = [&](std::size_t at) {
      std::uint64_t x;
      std::memcpy(&x, f.data() + at, 8);
      return x;
    };
    if (f.size() < 68 || f.substr(0, 13) != "ADAPTISO-GRID") return std::nullopt;
    GridSections s;
    s.version = u32(16);
    s.flags = u32(20);
    if (s.version < 2 || s.version > 6) return std::nullopt;
    const std::uint64_t M = u64(24), N = u64(32), T = u64(40), E = u64(48);
    s.depth = u32(56);
    s.reserved = u32(60);
    const bool index = s.flags & kHasIndex, hierarchy = s.flags & kHasHierarchy, moves = s.flags & kHasDisplacement;
    // Without the index, from version 6, the depth loading builds it at (up to 24).
    if (s.depth > 30 || (!index && s.depth > (s.version >= 6 ? 24u : 0u))) return std::nullopt;
    const std::uint64_t nodes = index ? (std::uint64_t{2} << s.depth) - 1 : 0;
    // Counts that cannot fit the file are refused before any multiplication can overflow.
    if (M > f.size() || N > f.size() || T > f.size() || E > f.size() || nodes > f.size()) return std::nullopt;
    const std::uint64_t need = 64 + M + N * 32 + T * 16 + nodes * 24 + E * 8 + (hierarchy ? 40 + N * 9 + (moves ? N : 0) : 0) + 4;
    if (need != f.size()) return std::nullopt;
    std::size_t at = 64;
    auto take = [&](std::uint64_t n) {
      std::string out(f.substr(at, n));
      at += n;
      return out;
    };
    s.meta = take(M);
    s.ijk = take(N * 12);
    s.values = take(N * 8);
    s.gradients = take(N * 12);
    s.tets = take(T * 16);
    s.nodes = take(nodes * 24);
    s.by_min = take(E * 4);
    s.by_max = take(E * 4);
    if (hierarchy) {
      s.hierarchy_head = take(40);
      s.error_codes = take(N);
      if (moves) s.displacement_codes = take(N);
      s.spans = take(N * 8);
    }
    return s;
  }

  // The file: counts from the sections' sizes (cut down to whole records), flags as they are, and
  // the checksum of what precedes it (restarted after every empty array up to version 4, as those
  // writers did).
  std::string assemble() const {
    std::string f(64, '\0');
    auto put32 = [&](std::size_t at, std::uint32_t x) { std::memcpy(f.data() + at, &x, 4); };
    auto put64 = [&](std::size_t at, std::uint64_t x) { std::memcpy(f.data() + at, &x, 8); };
    std::memcpy(f.data(), "ADAPTISO-GRID\0\0\0", 16);
    put32(16, version);
    put32(20, flags);
    put64(24, meta.size());
    put64(32, vertices());
    put64(40, tetrahedra());
    put64(48, by_min.size() / 4);
    put32(56, depth);
    put32(60, reserved);
    std::size_t covered = 0;  // where the checksum starts
    auto add = [&](const std::string& part, bool array) {
      if (array && part.empty() && version <= 4) covered = f.size();
      f += part;
    };
    add(meta, false);
    for (const std::string* a : {&ijk, &values, &gradients, &tets}) add(*a, true);
    if (flags & kHasIndex) {
      add(nodes, true);
      add(by_min, true);
      add(by_max, true);
    }
    if (flags & kHasHierarchy) {
      add(hierarchy_head, false);
      add(error_codes, true);
      if (flags & kHasDisplacement) add(displacement_codes, true);
      add(spans, true);
    }
    std::uint32_t crc = 0;
    for (std::size_t at = covered; at < f.size(); at += std::size_t{1} << 30)  // uInt lengths
      crc = static_cast<std::uint32_t>(
          crc32(crc, reinterpret_cast<const Bytef*>(f.data() + at), static_cast<uInt>(std::min(f.size() - at, std::size_t{1} << 30))));
    f.append(reinterpret_cast<const char*>(&crc), 4);
    return f;
  }

  // Typed access to record r of a section (element `e` of its `per`-element records).
  template <class T>
  static T get(const std::string& section, std::size_t r, std::size_t per = 1, std::size_t e = 0) {
    T x;
    std::memcpy(&x, section.data() + (r * per + e) * sizeof(T), sizeof(T));
    return x;
  }
  template <class T>
  static void set(std::string& section, std::size_t r, T x, std::size_t per = 1, std::size_t e = 0) {
    std::memcpy(section.data() + (r * per + e) * sizeof(T), &x, sizeof(T));
  }

  // The per-vertex sections, in the file's order, with their record sizes: what a change of the
  // vertices (an order, a removal) must change alike.
  std::vector<std::pair<std::string*, std::size_t>> vertex_sections() {
    std::vector<std::pair<std::string*, std::size_t>> out{{&ijk, 12}, {&values, 8}, {&gradients, 12}};
    if (!hierarchy_head.empty()) {
      out.push_back({&error_codes, 1});
      if (!displacement_codes.empty()) out.push_back({&displacement_codes, 1});
      out.push_back({&spans, 8});
    }
    return out;
  }
};

// One structure-aware mutation of a grid file's sections, chosen by rng (a callable returning
// 64 random bits): the kinds of lie a file can tell once its checksum is made to match. Structural
// mutations change how the file describes its data (which voxels are vertices and in what order,
// the tetrahedra, the index, the hierarchy's header and value spans, the metadata, the layout);
// with `data`, mutations of the data itself are among them too (values, gradients, error codes),
// which describe another volume and cannot be told from a real one without it. Returns the kind's
// name.
template <class Rng>
const char* mutate_sections(GridSections& s, Rng& rng, bool data) {
  auto below = [&](std::uint64_t n) { return n ? rng() % n : 0; };
  const std::size_t nv = s.vertices(), nt = s.tetrahedra();
  auto tet = [&](std::size_t t, std::size_t k) { return GridSections::get<std::uint32_t>(s.tets, t, 4, k); };
  auto set_tet = [&](std::size_t t, std::size_t k, std::uint32_t v) { GridSections::set<std::uint32_t>(s.tets, t, v, 4, k); };
  // Vertices moved by `order` (new position i holds old vertex order[i]; kNone-free), every
  // per-vertex section alike and the tetrahedra re-pointed by `renumber` (old → new).
  auto reorder = [&](const std::vector<std::uint32_t>& order, const std::vector<std::uint32_t>& renumber) {
    for (auto [section, bytes] : s.vertex_sections()) {
      if (section->size() != nv * bytes) continue;  // an earlier mutation cut it
      std::string out;
      out.reserve(order.size() * bytes);
      for (std::uint32_t o : order) out.append(*section, o * bytes, bytes);
      *section = std::move(out);
    }
    for (std::size_t t = 0; t < nt; ++t)
      for (std::size_t k = 0; k < 4; ++k)
        if (tet(t, k) < renumber.size()) set_tet(t, k, renumber[tet(t, k)]);
  };
  auto edit_json = [&](auto&& edit) {
    auto j = nlohmann::json::parse(s.meta, nullptr, false);
    if (j.is_discarded() || !j.is_object() || !j.contains("source") || !j["source"].is_object()) return;
    edit(j["source"]);
    s.meta = j.dump();
  };
  auto flip_bytes = [&](std::string& section) {
    if (section.empty()) return;
    for (int n = 1 + static_cast<int>(below(3)); n > 0; --n) section[below(section.size())] ^= static_cast<char>(1u << below(8));
  };
  constexpr int kStructural = 16, kData = 4;
  const int kind = static_cast<int>(below(data ? kStructural + kData : kStructural));
  switch (kind) {
    case 0: {  // two vertices swapped, tetrahedra re-pointed: the same grid in another order
      if (nv < 2) return "none";
      std::vector<std::uint32_t> order(nv);
      std::iota(order.begin(), order.end(), 0u);
      std::swap(order[below(nv)], order[below(nv)]);
      reorder(order, order);  // a swap is its own inverse
      return "swap vertices";
    }
    case 1: {  // every vertex moved, consistently
      if (nv < 2) return "none";
      std::vector<std::uint32_t> order(nv), renumber(nv);
      std::iota(order.begin(), order.end(), 0u);
      for (std::size_t i = nv - 1; i > 0; --i) std::swap(order[i], order[below(i + 1)]);
      for (std::uint32_t i = 0; i < nv; ++i) renumber[order[i]] = i;
      reorder(order, renumber);
      return "permute vertices";
    }
    case 2: {  // a vertex removed, its tetrahedra re-pointed to another
      if (nv < 2) return "none";
      const auto gone = static_cast<std::uint32_t>(below(nv));
      const auto instead = static_cast<std::uint32_t>(gone + 1 < nv ? gone + 1 : gone - 1);
      std::vector<std::uint32_t> order, renumber(nv);
      for (std::uint32_t i = 0; i < nv; ++i) {
        if (i != gone) order.push_back(i);
        renumber[i] = i < gone ? i : i == gone ? (instead < gone ? instead : instead - 1) : i - 1;
      }
      reorder(order, renumber);
      return "remove a vertex";
    }
    case 3: {  // a vertex repeated
      if (nv < 1) return "none";
      const auto twice = static_cast<std::uint32_t>(below(nv));
      std::vector<std::uint32_t> order, renumber(nv);
      for (std::uint32_t i = 0; i < nv; ++i) {
        order.push_back(i);
        if (i == twice) order.push_back(i);
        renumber[i] = i <= twice ? i : i + 1;
      }
      reorder(order, renumber);
      return "repeat a vertex";
    }
    case 4: {  // a tetrahedron removed or repeated
      if (nt < 1) return "none";
      const std::size_t t = below(nt);
      if (rng() & 1)
        s.tets.erase(t * 16, 16);
      else
        s.tets.insert(t * 16, s.tets.substr(t * 16, 16));
      return "remove or repeat a tetrahedron";
    }
    case 5: {  // two tetrahedra swapped, or two corners of one (its orientation)
      if (nt < 2) return "none";
      if (rng() & 1) {
        const std::size_t a = below(nt), b = below(nt);
        std::string ta = s.tets.substr(a * 16, 16);
        s.tets.replace(a * 16, 16, s.tets.substr(b * 16, 16));
        s.tets.replace(b * 16, 16, ta);
      } else {
        const std::size_t t = below(nt), a = below(4), b = below(4);
        const std::uint32_t va = tet(t, a);
        set_tet(t, a, tet(t, b));
        set_tet(t, b, va);
      }
      return "swap tetrahedra or corners";
    }
    case 6: {  // a corner re-pointed
      if (nt < 1 || nv < 1) return "none";
      set_tet(below(nt), below(4), static_cast<std::uint32_t>(rng() % 8 == 0 ? rng() : below(nv)));
      return "re-point a corner";
    }
    case 7: {  // the metadata's geometry and types
      static const double odd[] = {0, -1, 1e308, -1e308, 5e-324, 1e-30, 1e30, 2, 0.5, 1e-300, 3};
      edit_json([&](nlohmann::json& src) {
        const char* keys[] = {"spacing", "origin", "direction", "dims"};
        const char* key = keys[below(4)];
        if (!src.contains(key) || !src[key].is_array() || src[key].empty()) return;
        auto& a = src[key];
        const std::size_t i = below(a.size());
        switch (below(4)) {
          case 0:
            a.push_back(a[i]);  // a fourth entry
            break;
          case 1:
            a.erase(i);
            break;
          case 2:
            if (a[i].is_number()) a[i] = a[i].get<double>() * odd[below(std::size(odd))];
            break;
          default:
            if (std::string(key) == "dims" && a[i].is_number_integer() && std::abs(a[i].get<std::int64_t>()) < (std::int64_t{1} << 40))
              a[i] = rng() % 4 ? a[i].get<std::int64_t>() + static_cast<std::int64_t>(below(3)) - 1 : (std::int64_t{1} << 30) + 1;
            else
              a[i] = odd[below(std::size(odd))];
        }
      });
      return "metadata geometry";
    }
    case 8: {  // the metadata's values, type, method and bound
      edit_json([&](nlohmann::json& src) {
        switch (below(7)) {
          case 0:
            if (src.contains("min") && src.contains("max")) std::swap(src["min"], src["max"]);
            break;
          case 1:
            if (src["min"].is_number()) src["min"] = src["min"].get<double>() - 1 - static_cast<double>(below(1000));
            break;
          case 2:
            src["type"] = std::array<const char*, 5>{"int16", "float64", "uint8", "quaternion", ""}[below(5)];
            break;
          case 3:
            src["method"] = std::array<const char*, 3>{"bisection", "reconstruction", "test"}[below(3)];
            break;
          case 4:
            if (src["max_error"].is_number())
              src["max_error"] = src["max_error"].get<double>() * std::array<double, 4>{0, 2, 1.0001, -1}[below(4)];
            else
              src["max_error"] = 1.0;
            break;
          case 5:
            src.erase(std::array<const char*, 4>{"dims", "type", "min", "file"}[below(4)]);
            break;
          default:
            src["dims"] = nlohmann::json::array({17, 17, 17});
        }
      });
      return "metadata values";
    }
    case 9: {  // the hierarchy's header: root size, thresholds, reserved, scales
      if (s.hierarchy_head.size() != 40) return "none";
      switch (below(4)) {
        case 0:
          GridSections::set<std::uint32_t>(s.hierarchy_head, 0,
                                           GridSections::get<std::uint32_t>(s.hierarchy_head, 0) * 2);  // unsigned: no overflow
          break;
        case 1:
          s.hierarchy_head[4 + below(2)] = static_cast<char>(static_cast<std::uint8_t>(s.hierarchy_head[4]) + (rng() & 1 ? 1 : 255));
          break;
        case 2:
          s.hierarchy_head[6 + below(2)] = 1;
          break;
        default: {
          const std::size_t at = 8 + 8 * below(4);
          double x;
          std::memcpy(&x, s.hierarchy_head.data() + at, 8);
          x = rng() & 1 ? x * 2 : std::nextafter(x, std::numeric_limits<double>::infinity());
          std::memcpy(s.hierarchy_head.data() + at, &x, 8);
        }
      }
      return "hierarchy header";
    }
    case 10: {  // value spans: one narrowed, widened, emptied or two swapped
      // Records counted in the section itself: a mutation of its bytes may have changed its size.
      const std::size_t n = s.spans.size() / 8;
      if (n == 0) return "none";
      const std::size_t v = below(n);
      auto span = [&](std::size_t i, std::size_t e) { return GridSections::get<float>(s.spans, i, 2, e); };
      switch (below(4)) {
        case 0:
          GridSections::set<float>(s.spans, v, std::nextafter(span(v, 0), std::numeric_limits<float>::infinity()), 2, 0);
          break;
        case 1:
          GridSections::set<float>(s.spans, v, span(v, 1) + 1, 2, 1);
          break;
        case 2:
          GridSections::set<float>(s.spans, v, std::numeric_limits<float>::infinity(), 2, 0);
          GridSections::set<float>(s.spans, v, -std::numeric_limits<float>::infinity(), 2, 1);
          break;
        default: {
          const std::size_t w = below(n);
          const std::string a = s.spans.substr(v * 8, 8);
          s.spans.replace(v * 8, 8, s.spans.substr(w * 8, 8));
          s.spans.replace(w * 8, 8, a);
        }
      }
      return "value spans";
    }
    case 11: {  // the index: lists and nodes
      std::string* parts[] = {&s.nodes, &s.by_min, &s.by_max};
      std::string& part = *parts[below(3)];
      if (part.size() < 8) return "none";
      if (rng() & 1) {
        flip_bytes(part);
      } else {
        const std::size_t a = below(part.size() / 4), b = below(part.size() / 4);
        std::swap_ranges(part.begin() + static_cast<long>(a * 4), part.begin() + static_cast<long>(a * 4 + 4),
                         part.begin() + static_cast<long>(b * 4));
      }
      return "index";
    }
    case 12:  // the index dropped (loading builds one)
      s.flags &= ~GridSections::kHasIndex;
      s.nodes.clear();
      s.by_min.clear();
      s.by_max.clear();
      s.depth = 0;
      return "drop the index";
    case 13:  // the hierarchy dropped, or claimed without its arrays
      if (rng() & 1) {
        s.flags &= ~(GridSections::kHasHierarchy | GridSections::kHasDisplacement);
        s.hierarchy_head.clear();
        s.error_codes.clear();
        s.displacement_codes.clear();
        s.spans.clear();
      } else {
        s.flags |= GridSections::kHasHierarchy;
      }
      return "drop or claim the hierarchy";
    case 14: {  // bits flipped in a section that describes structure
      std::string* parts[] = {&s.ijk, &s.tets, &s.hierarchy_head, &s.spans, &s.meta};
      flip_bytes(*parts[below(5)]);
      return "flip structure bits";
    }
    case 15: {  // everything but the header's first vertices and tetrahedra: an empty or cut grid
      const std::size_t keep = below(std::min<std::size_t>(nv, 8) + 1);
      for (auto [section, bytes] : s.vertex_sections()) section->resize(keep * bytes);
      s.tets.resize(below(std::min<std::size_t>(nt, 8) + 1) * 16);
      return "cut the grid";
    }
    case kStructural + 0: {  // a value changed
      if (s.values.size() < 8) return "none";
      const std::size_t v = below(s.values.size() / 8);
      const double x = GridSections::get<double>(s.values, v);
      GridSections::set<double>(s.values, v, rng() & 1 ? std::nextafter(x, 1e300) : x + static_cast<double>(below(100)) - 50);
      return "change a value";
    }
    case kStructural + 1:
      flip_bytes(s.gradients);
      return "flip gradient bits";
    case kStructural + 2: {  // an error or displacement code changed
      std::string& codes = !s.displacement_codes.empty() && (rng() & 1) ? s.displacement_codes : s.error_codes;
      if (codes.empty()) return "none";
      const std::size_t v = below(codes.size());
      codes[v] = static_cast<char>(
          std::array<int, 4>{0, 255, static_cast<std::uint8_t>(codes[v]) + 1, static_cast<std::uint8_t>(codes[v]) - 1}[below(4)]);
      return "change a code";
    }
    default:
      flip_bytes(rng() & 1 ? s.values : s.error_codes);
      return "flip data bits";
  }
}

}  // namespace adaptiso::detail
