// adaptiso/progress.hpp — how long-running stages report progress.
//
// A stage calls progress(stage_name, fraction in [0,1]) now and then (from any thread, at most a
// few hundred times per stage). An empty function means nobody listens. The CLI draws a status
// line on a terminal; the viewer forwards it to the page.
#pragma once
#include <functional>
#include <string_view>

namespace adaptiso {

using Progress = std::function<void(std::string_view stage, double fraction)>;

inline void report(const Progress& p, std::string_view stage, double fraction) {
  if (p) p(stage, fraction);
}

}  // namespace adaptiso
