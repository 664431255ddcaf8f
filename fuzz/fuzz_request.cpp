// The viewer's request parameters: the query string decoded by cpp-httplib, as the server does,
// then every parameter parser a handler calls. BadRequest (HTTP 400) is the expected answer.
#include <httplib.h>

#include "fuzz_util.hpp"
#include "view/request.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  httplib::Params params;
  httplib::detail::parse_query_text(std::string(fuzz::as_view(data, size)), params);
  using namespace adaptiso::detail;
  auto quietly = [](auto&& f) {
    try {
      f();
    } catch (const BadRequest&) {
    }
  };
  quietly([&] { parse_iso(params); });
  quietly([&] { client_id(params); });
  quietly([&] { compact_format(params); });
  quietly([&] { export_format(params); });
  for (const char* name : {"error", "budget", "simplify", "distance"}) quietly([&] { parse_optional(params, name); });
  quietly([&] {
    const int rounds = parse_rounds(params, "collapse", 2, 16);
    if (rounds < 0 || rounds > 16) __builtin_trap();  // a refusal, never a number out of range
  });
  return 0;
}
