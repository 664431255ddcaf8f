// The viewer's request parameters (see request.hpp).
#include "view/request.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>

#include "adaptiso/number.hpp"

namespace adaptiso::detail {
namespace {

const std::string* param(const QueryParams& params, const char* name) {
  auto it = params.find(name);
  return it == params.end() ? nullptr : &it->second;
}

}  // namespace

double parse_iso(const QueryParams& params) {
  const std::string* s = param(params, "iso");
  if (!s) throw BadRequest("missing parameter iso");
  auto x = parse_finite(*s);
  if (!x) throw BadRequest(fmt::format("iso must be a finite number, not '{}'", s->substr(0, 40)));
  return *x;
}

std::optional<double> parse_optional(const QueryParams& params, const char* name) {
  const std::string* s = param(params, name);
  if (!s) return std::nullopt;
  auto x = parse_finite(*s);
  if (!x || *x < 0) throw BadRequest(fmt::format("{} must be a non-negative number, not '{}'", name, s->substr(0, 40)));
  return x;
}

int parse_rounds(const QueryParams& params, const char* name, int fallback, int max) {
  const std::string* s = param(params, name);
  if (!s) return fallback;
  const auto x = parse_finite(*s);
  if (!x || *x < 0 || *x > max || *x != std::floor(*x))
    throw BadRequest(fmt::format("{} must be a whole number from 0 to {}, not '{}'", name, max, s->substr(0, 40)));
  return static_cast<int>(*x);
}

bool parse_flag(const QueryParams& params, const char* name) {
  const std::string* s = param(params, name);
  if (!s || *s == "0" || *s == "false") return false;
  if (*s == "1" || *s == "true") return true;
  throw BadRequest(fmt::format("{} must be 0, 1, true or false, not '{}'", name, s->substr(0, 40)));
}

bool compact_format(const QueryParams& params) {
  const std::string* f = param(params, "format");
  if (!f) return false;
  if (*f != "plain" && *f != "compact") throw BadRequest("format must be plain or compact");
  return *f == "compact";
}

std::string export_format(const QueryParams& params) {
  const std::string* f = param(params, "format");
  if (!f) return "glb";
  if (*f != "glb" && *f != "ply") throw BadRequest("format must be glb or ply");
  return *f;
}

std::string client_id(const QueryParams& params) {
  const std::string* c = param(params, "client");
  if (!c) return "default";
  if (c->empty() || c->size() > 64 ||
      !std::all_of(c->begin(), c->end(), [](char ch) { return std::isalnum(static_cast<unsigned char>(ch)) || ch == '-' || ch == '_'; }))
    throw BadRequest("client must be 1-64 letters, digits, '-' or '_'");
  return *c;
}

}  // namespace adaptiso::detail
