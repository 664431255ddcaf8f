// Mesh files (see mesh_io.hpp): PLY, OBJ, STL, glTF binary writers and a PLY reader.
#include "adaptiso/mesh_io.hpp"

#define TINYGLTF_IMPLEMENTATION
#define TINYGLTF_NO_STB_IMAGE
#define TINYGLTF_NO_STB_IMAGE_WRITE
#define TINYGLTF_NO_EXTERNAL_IMAGE
#define TINYGLTF_USE_CPP14
#include <tiny_gltf.h>

#include <fmt/format.h>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/error.hpp"
#include "volume/io_util.hpp"

namespace adaptiso {
namespace {

template <class T>
void put(std::ostream& o, const T& x) {
  o.write(reinterpret_cast<const char*>(&x), sizeof x);
}

void write_ply(const Mesh& m, std::ostream& o) {
  const bool normals = m.normals.size() == m.positions.size() && !m.positions.empty();
  o << "ply\nformat binary_little_endian 1.0\ncomment adaptiso iso-surface\n"
    << "element vertex " << m.positions.size() << "\nproperty float x\nproperty float y\nproperty float z\n";
  if (normals) o << "property float nx\nproperty float ny\nproperty float nz\n";
  o << "element face " << m.triangles.size() << "\nproperty list uchar uint vertex_indices\nend_header\n";
  std::vector<char> buf;
  const std::size_t vsz = normals ? 24 : 12;
  buf.resize(m.positions.size() * vsz);
  for (std::size_t i = 0; i < m.positions.size(); ++i) {
    std::memcpy(&buf[i * vsz], m.positions[i].data(), 12);
    if (normals) std::memcpy(&buf[i * vsz + 12], m.normals[i].data(), 12);
  }
  o.write(buf.data(), static_cast<std::streamsize>(buf.size()));
  buf.resize(m.triangles.size() * 13);
  for (std::size_t i = 0; i < m.triangles.size(); ++i) {
    buf[i * 13] = 3;
    std::memcpy(&buf[i * 13 + 1], m.triangles[i].data(), 12);
  }
  o.write(buf.data(), static_cast<std::streamsize>(buf.size()));
}

void write_obj(const Mesh& m, std::ostream& o) {
  const bool normals = m.normals.size() == m.positions.size() && !m.positions.empty();
  o << "# adaptiso iso-surface\n";
  std::string s;
  for (const auto& p : m.positions) s += fmt::format("v {} {} {}\n", p[0], p[1], p[2]);
  if (normals)
    for (const auto& n : m.normals) s += fmt::format("vn {} {} {}\n", n[0], n[1], n[2]);
  for (const auto& t : m.triangles)
    s += normals ? fmt::format("f {0}//{0} {1}//{1} {2}//{2}\n", t[0] + 1, t[1] + 1, t[2] + 1)
                 : fmt::format("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
  o << s;
}

void write_stl(const Mesh& m, std::ostream& o) {
  char header[80] = {};
  std::snprintf(header, sizeof header, "adaptiso iso-surface");
  o.write(header, 80);
  if (m.triangles.size() > std::numeric_limits<std::uint32_t>::max()) throw InputError("too many triangles for STL");
  put(o, static_cast<std::uint32_t>(m.triangles.size()));
  std::vector<char> buf(m.triangles.size() * 50);
  for (std::size_t i = 0; i < m.triangles.size(); ++i) {
    const auto& a = m.positions[m.triangles[i][0]];
    const auto& b = m.positions[m.triangles[i][1]];
    const auto& c = m.positions[m.triangles[i][2]];
    double u[3], v[3], n[3];
    for (int k = 0; k < 3; ++k) u[k] = double(b[k]) - a[k], v[k] = double(c[k]) - a[k];
    n[0] = u[1] * v[2] - u[2] * v[1];
    n[1] = u[2] * v[0] - u[0] * v[2];
    n[2] = u[0] * v[1] - u[1] * v[0];
    double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    float fn[3] = {0, 0, 0};
    if (len > 0)
      for (int k = 0; k < 3; ++k) fn[k] = static_cast<float>(n[k] / len);
    char* r = &buf[i * 50];
    std::memcpy(r, fn, 12);
    std::memcpy(r + 12, a.data(), 12);
    std::memcpy(r + 24, b.data(), 12);
    std::memcpy(r + 36, c.data(), 12);
    r[48] = r[49] = 0;
  }
  o.write(buf.data(), static_cast<std::streamsize>(buf.size()));
}

void write_glb(const Mesh& m, std::ostream& o) {
  tinygltf::Model model;
  model.asset.version = "2.0";
  model.asset.generator = "adaptiso";
  const bool normals = m.normals.size() == m.positions.size() && !m.positions.empty();
  tinygltf::Buffer buffer;
  auto append = [&](const void* p, std::size_t n) {
    std::size_t off = buffer.data.size();
    buffer.data.resize(off + n);
    if (n) std::memcpy(buffer.data.data() + off, p, n);
    return off;
  };
  const std::size_t pos_off = append(m.positions.data(), m.positions.size() * 12);
  const std::size_t nrm_off = normals ? append(m.normals.data(), m.normals.size() * 12) : 0;
  const std::size_t idx_off = append(m.triangles.data(), m.triangles.size() * 12);
  model.buffers.push_back(std::move(buffer));
  auto view = [&](std::size_t off, std::size_t len, int target) {
    tinygltf::BufferView v;
    v.buffer = 0;
    v.byteOffset = off;
    v.byteLength = len;
    v.target = target;
    model.bufferViews.push_back(v);
    return static_cast<int>(model.bufferViews.size() - 1);
  };
  tinygltf::Primitive prim;
  prim.mode = TINYGLTF_MODE_TRIANGLES;
  {
    tinygltf::Accessor a;
    a.bufferView = view(pos_off, m.positions.size() * 12, TINYGLTF_TARGET_ARRAY_BUFFER);
    a.componentType = TINYGLTF_COMPONENT_TYPE_FLOAT;
    a.count = m.positions.size();
    a.type = TINYGLTF_TYPE_VEC3;
    std::vector<double> lo(3, 0), hi(3, 0);
    for (std::size_t i = 0; i < m.positions.size(); ++i)
      for (int k = 0; k < 3; ++k) {
        lo[k] = i ? std::min<double>(lo[k], m.positions[i][k]) : m.positions[i][k];
        hi[k] = i ? std::max<double>(hi[k], m.positions[i][k]) : m.positions[i][k];
      }
    a.minValues = lo;  // required for POSITION by the glTF specification
    a.maxValues = hi;
    model.accessors.push_back(a);
    prim.attributes["POSITION"] = static_cast<int>(model.accessors.size() - 1);
  }
  if (normals) {
    tinygltf::Accessor a;
    a.bufferView = view(nrm_off, m.normals.size() * 12, TINYGLTF_TARGET_ARRAY_BUFFER);
    a.componentType = TINYGLTF_COMPONENT_TYPE_FLOAT;
    a.count = m.normals.size();
    a.type = TINYGLTF_TYPE_VEC3;
    model.accessors.push_back(a);
    prim.attributes["NORMAL"] = static_cast<int>(model.accessors.size() - 1);
  }
  {
    tinygltf::Accessor a;
    a.bufferView = view(idx_off, m.triangles.size() * 12, TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER);
    a.componentType = TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT;
    a.count = m.triangles.size() * 3;
    a.type = TINYGLTF_TYPE_SCALAR;
    model.accessors.push_back(a);
    prim.indices = static_cast<int>(model.accessors.size() - 1);
  }
  tinygltf::Mesh gm;
  gm.name = "isosurface";
  gm.primitives.push_back(prim);
  model.meshes.push_back(gm);
  tinygltf::Node node;
  node.mesh = 0;
  model.nodes.push_back(node);
  tinygltf::Scene scene;
  scene.nodes.push_back(0);
  model.scenes.push_back(scene);
  model.defaultScene = 0;
  tinygltf::TinyGLTF writer;
  if (!writer.WriteGltfSceneToStream(&model, o, false, true)) throw std::runtime_error("glTF writer failed");
}

std::string lower_extension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (auto& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}

}  // namespace

bool is_mesh_file_name(const std::string& path) {
  const std::string ext = lower_extension(path);
  return ext == ".ply" || ext == ".obj" || ext == ".stl" || ext == ".glb";
}

namespace {

using Writer = void (*)(const Mesh&, std::ostream&);

Writer writer_for(const std::string& path) {
  const std::string ext = lower_extension(path);
  if (ext == ".ply") return write_ply;
  if (ext == ".obj") return write_obj;
  if (ext == ".stl") return write_stl;
  if (ext == ".glb") return write_glb;
  throw InputError(fmt::format("{}: unknown mesh type '{}' (use .ply, .obj, .stl or .glb)", path, ext));
}

}  // namespace

StagedFile stage_mesh(const Mesh& m, const std::string& path) {
  const Writer writer = writer_for(path);
  return StagedFile(path, [&](std::ostream& o) { writer(m, o); });
}

void write_mesh(const Mesh& m, const std::string& path) { stage_mesh(m, path).commit(); }

std::string mesh_file_bytes(const Mesh& m, const std::string& name) {
  const Writer writer = writer_for(name);
  std::ostringstream o(std::ios::binary);
  writer(m, o);
  return std::move(o).str();
}

// ---- PLY reader ----
namespace {

struct Property {
  std::string name, type, count_type;  // count_type non-empty for lists
};
struct Element {
  std::string name;
  std::uint64_t count = 0;
  std::vector<Property> props;
};

std::size_t type_size(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" || t == "float32") return 4;
  if (t == "double" || t == "float64") return 8;
  return 0;
}

class PlyIn {
public:
  PlyIn(std::istream& in, int fmt, std::string path) : in_(in), fmt_(fmt), path_(std::move(path)) {}
  double read(const std::string& t) {
    if (fmt_ == 0) {
      double d;
      if (!(in_ >> d)) fail("truncated or malformed ASCII data");
      return d;
    }
    unsigned char b[8];
    std::size_t n = type_size(t);
    if (!in_.read(reinterpret_cast<char*>(b), static_cast<std::streamsize>(n))) fail("truncated");
    if (fmt_ == 2) std::reverse(b, b + n);
    auto get = [&](auto x) {
      std::memcpy(&x, b, sizeof x);
      return static_cast<double>(x);
    };
    if (t == "char" || t == "int8") return get(std::int8_t{});
    if (t == "uchar" || t == "uint8") return get(std::uint8_t{});
    if (t == "short" || t == "int16") return get(std::int16_t{});
    if (t == "ushort" || t == "uint16") return get(std::uint16_t{});
    if (t == "int" || t == "int32") return get(std::int32_t{});
    if (t == "uint" || t == "uint32") return get(std::uint32_t{});
    if (t == "float" || t == "float32") return get(float{});
    return get(double{});
  }
  [[noreturn]] void fail(const std::string& why) { throw InputError(fmt::format("{}: not a valid PLY file ({})", path_, why)); }

private:
  std::istream& in_;
  int fmt_;
  std::string path_;
};

}  // namespace

Mesh read_ply(const std::string& path) {
  detail::file_size_or_throw(path);  // a FIFO or device would block or never end
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) throw InputError(fmt::format("{}: cannot open mesh file", path));
  const std::uint64_t size = static_cast<std::uint64_t>(in.tellg());
  in.seekg(0);
  auto fail = [&](const std::string& why) { throw InputError(fmt::format("{}: not a valid PLY file ({})", path, why)); };
  std::string line;
  if (!std::getline(in, line) || line.substr(0, 3) != "ply") fail("no 'ply' magic");
  int fmt = -1;
  std::vector<Element> elems;
  for (int lines = 0;; ++lines) {
    if (lines > 10000 || !std::getline(in, line)) fail("header has no end_header");
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ls(line);
    std::string w;
    ls >> w;
    if (w == "end_header") break;
    if (w == "format") {
      std::string f;
      ls >> f;
      fmt = f == "ascii" ? 0 : f == "binary_little_endian" ? 1 : f == "binary_big_endian" ? 2 : -1;
      if (fmt < 0) fail("unknown format " + f);
    } else if (w == "element") {
      Element e;
      if (!(ls >> e.name >> e.count)) fail("bad element line");
      if (e.count > size) fail("element count exceeds the file size");
      elems.push_back(e);
    } else if (w == "property") {
      if (elems.empty()) fail("property before element");
      Property p;
      ls >> p.type;
      if (p.type == "list") ls >> p.count_type >> p.type;
      ls >> p.name;
      if (!type_size(p.type) || (!p.count_type.empty() && !type_size(p.count_type))) fail("unknown property type");
      elems.back().props.push_back(p);
    }
  }
  if (fmt < 0) fail("no format line");
  Mesh m;
  PlyIn r(in, fmt, path);
  for (const auto& e : elems) {
    if (e.name == "vertex") {
      int ix[6] = {-1, -1, -1, -1, -1, -1};
      const char* names[6] = {"x", "y", "z", "nx", "ny", "nz"};
      for (std::size_t k = 0; k < e.props.size(); ++k)
        for (int a = 0; a < 6; ++a)
          if (e.props[k].name == names[a] && e.props[k].count_type.empty()) ix[a] = static_cast<int>(k);
      if (ix[0] < 0 || ix[1] < 0 || ix[2] < 0) fail("vertex has no x, y, z");
      const bool normals = ix[3] >= 0 && ix[4] >= 0 && ix[5] >= 0;
      m.positions.reserve(e.count);
      std::vector<double> rec(e.props.size());
      for (std::uint64_t i = 0; i < e.count; ++i) {
        for (std::size_t k = 0; k < e.props.size(); ++k) {
          if (!e.props[k].count_type.empty()) {
            const double count = r.read(e.props[k].count_type);
            if (!(count >= 0 && count <= 1000)) fail("bad list length");  // checked before the cast: 1e28 has no integer
            const auto n = static_cast<std::uint64_t>(count);
            for (std::uint64_t q = 0; q < n; ++q) r.read(e.props[k].type);
            rec[k] = 0;
          } else {
            rec[k] = r.read(e.props[k].type);
          }
        }
        m.positions.push_back({float(rec[ix[0]]), float(rec[ix[1]]), float(rec[ix[2]])});
        if (normals) m.normals.push_back({float(rec[ix[3]]), float(rec[ix[4]]), float(rec[ix[5]])});
      }
    } else {
      const bool faces = e.name == "face";
      for (std::uint64_t i = 0; i < e.count; ++i) {
        for (const auto& p : e.props) {
          if (p.count_type.empty()) {
            r.read(p.type);
            continue;
          }
          auto n = r.read(p.count_type);
          if (!(n >= 0 && n <= 1000)) fail("bad list length");
          std::vector<std::uint32_t> poly(static_cast<std::size_t>(n));
          for (auto& v : poly) {
            double d = r.read(p.type);
            if (!(d >= 0 && d < static_cast<double>(m.positions.size()))) fail("face index out of range");
            v = static_cast<std::uint32_t>(d);
          }
          if (faces && (p.name == "vertex_indices" || p.name == "vertex_index"))
            for (std::size_t q = 2; q < poly.size(); ++q) m.triangles.push_back({poly[0], poly[q - 1], poly[q]});
        }
      }
    }
  }
  for (const auto& p : m.positions)
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) fail("non-finite vertex coordinate");
  return m;
}

}  // namespace adaptiso
