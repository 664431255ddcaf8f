// The shared datasets (../shared/data or $ADAPTISO_DATA) as tests see them: each <name>.txt sidecar
// (dimensions, type, value range) and the file or folder to open.
#pragma once
#include <fmt/format.h>

#include <algorithm>
#include <filesystem>
#include <regex>
#include <string>
#include <vector>

#include "adaptiso/volume.hpp"
#include "test_util.hpp"

namespace testutil {
namespace fs = std::filesystem;
using adaptiso::Dims;

struct Sidecar {
  std::string name;
  Dims dims{};
  std::string type;
  double min = 0, max = 0;
};

inline Sidecar parse_sidecar(const fs::path& txt) {
  const std::string s = testutil::read_bytes(txt);
  Sidecar c;
  c.name = txt.stem().string();
  std::smatch m;
  if (std::regex_search(s, m, std::regex(R"(Dimensions:\s+(\d+)\s*x\s*(\d+)\s*x\s*(\d+))")))
    c.dims = {std::stoll(m[1]), std::stoll(m[2]), std::stoll(m[3])};
  if (std::regex_search(s, m, std::regex(R"(Voxel type:\s+(\w+))"))) c.type = m[1];
  if (std::regex_search(s, m, std::regex(R"(min\s+(-?[\d.]+),\s*max\s+(-?[\d.]+))"))) {
    c.min = std::stod(m[1]);
    c.max = std::stod(m[2]);
  }
  return c;
}

// The file or folder to open for a dataset; unpacks archives into `tmp`.
inline std::string main_input(const std::string& data, const std::string& name, const fs::path& tmp) {
  for (const char* ext : {".nhdr", ".nrrd", ".mha", ".vti", ".vtk"})
    if (fs::exists(data + "/" + name + ext)) return data + "/" + name + ext;
  if (fs::is_directory(data + "/" + name)) {
    for (const auto& e : fs::directory_iterator(data + "/" + name))
      if (e.path().extension() == ".nhdr" || e.path().extension() == ".mhd") return e.path().string();
    return data + "/" + name;
  }
  if (fs::exists(data + "/" + name + ".tar.gz")) {
    std::string cmd = fmt::format("tar xzf '{}/{}.tar.gz' -C '{}'", data, name, tmp.string());
    if (std::system(cmd.c_str()) != 0) return "";
    return (tmp / name).string();
  }
  return "";
}

inline std::vector<std::string> dataset_names() {
  std::vector<std::string> n;
  std::string d = testutil::data_dir();
  if (d.empty()) return {"(no data folder)"};
  for (const auto& e : fs::directory_iterator(d))
    if (e.path().extension() == ".txt") n.push_back(e.path().stem().string());
  std::sort(n.begin(), n.end());
  return n;
}

}  // namespace testutil
