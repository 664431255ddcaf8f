// Internal: the viewer's request parameters, parsed and checked before a handler uses them. Kept
// apart from the server so a fuzzer can drive them with any query string (fuzz/fuzz_request.cpp).
#pragma once
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace adaptiso::detail {

// A malformed request: the server answers 400 with the message.
struct BadRequest : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// The decoded query parameters (httplib::Params is this multimap; the first value of a name counts).
using QueryParams = std::multimap<std::string, std::string>;

// iso=: a finite number, required.
double parse_iso(const QueryParams& params);
// An optional non-negative number parameter (error=, budget=, simplify=).
std::optional<double> parse_optional(const QueryParams& params, const char* name);
// collapse=: rounds of edge collapses after a distance query, a whole number from 0 to max;
// `fallback` when absent.
int parse_rounds(const QueryParams& params, const char* name, int fallback, int max);
// format=plain (the default) or format=compact (mesh_codec.hpp) for /api/surface.
bool compact_format(const QueryParams& params);
// A yes/no parameter: absent, 0 or false is no; 1 or true is yes; anything else a bad request.
bool parse_flag(const QueryParams& params, const char* name);
// format=glb (the default) or format=ply for /api/export.
std::string export_format(const QueryParams& params);
// client=: 1-64 letters, digits, '-' or '_'; "default" when absent.
std::string client_id(const QueryParams& params);

// The API's routes as the server registers them ("/api/info", ...; view_server.cpp): each is
// specified in docs/API.md (tests/view check both ways).
std::vector<std::string> api_routes();

}  // namespace adaptiso::detail
