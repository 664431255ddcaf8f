// The Python module `adaptiso` (pybind11): the library's pipeline where its users already work.
//
// Axis order. A numpy volume is indexed array[z, y, x] (C order: x varies fastest), which is the
// files' layout, so a C-contiguous array becomes a Volume without a copy (the Volume keeps the
// array alive and only reads it). Volume.spacing and Volume.origin are in (x, y, z) order, like
// the files and the command line, and meshes come back in world coordinates (x, y, z).
// marching_cubes() alone follows scikit-image: spacing and vertices in the array's index order.
//
// Every long call releases the GIL. Errors: OptionError → ValueError (bad arguments), InputError
// → OSError from read/load/save/write_mesh (unreadable or unwritable files) and ValueError
// elsewhere; the messages are the command line's one-liners.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "adaptiso/error.hpp"
#include "adaptiso/extractor.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/marching_cubes.hpp"
#include "adaptiso/mesh_io.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/version.hpp"
#include "adaptiso/volume_io.hpp"

namespace py = pybind11;
using namespace adaptiso;

namespace {

// Runs f with the GIL released; InputError becomes OSError (file operations).
template <class F>
auto file_call(F&& f) {
  try {
    py::gil_scoped_release release;
    return f();
  } catch (const OptionError&) {
    throw;
  } catch (const InputError& e) {  // the GIL is held again here
    PyErr_SetString(PyExc_OSError, e.what());
    throw py::error_already_set();
  }
}

// numpy dtype ↔ ScalarType.
ScalarType scalar_type_of(const py::dtype& d) {
  const char kind = d.kind();
  const auto size = d.itemsize();
  if (kind == 'u' && size == 1) return ScalarType::u8;
  if (kind == 'i' && size == 1) return ScalarType::i8;
  if (kind == 'u' && size == 2) return ScalarType::u16;
  if (kind == 'i' && size == 2) return ScalarType::i16;
  if (kind == 'u' && size == 4) return ScalarType::u32;
  if (kind == 'i' && size == 4) return ScalarType::i32;
  if (kind == 'f' && size == 4) return ScalarType::f32;
  if (kind == 'f' && size == 8) return ScalarType::f64;
  throw py::value_error("volume: unsupported dtype " + py::str(py::handle(d)).cast<std::string>() +
                        " (use uint8, int8, uint16, int16, uint32, int32, float32 or float64)");
}

py::dtype dtype_of(ScalarType t) {
  switch (t) {
    case ScalarType::u8:
      return py::dtype::of<std::uint8_t>();
    case ScalarType::i8:
      return py::dtype::of<std::int8_t>();
    case ScalarType::u16:
      return py::dtype::of<std::uint16_t>();
    case ScalarType::i16:
      return py::dtype::of<std::int16_t>();
    case ScalarType::u32:
      return py::dtype::of<std::uint32_t>();
    case ScalarType::i32:
      return py::dtype::of<std::int32_t>();
    case ScalarType::f32:
      return py::dtype::of<float>();
    case ScalarType::f64:
      return py::dtype::of<double>();
  }
  throw std::logic_error("unknown scalar type");
}

// A numpy array of shape (nz, ny, nx) as a Volume: a view of its memory when it is C-contiguous
// and in native byte order, a copy otherwise. The view holds a reference to the array, released
// with the GIL held whichever thread drops the Volume last.
std::shared_ptr<Volume> volume_from_array(const py::array& input, const Vec3& spacing, const Vec3& origin) {
  if (input.ndim() != 3) throw py::value_error("volume: the array must have 3 dimensions [z, y, x], got " + std::to_string(input.ndim()));
  const ScalarType type = scalar_type_of(input.dtype());
  py::array a = py::array::ensure(input, py::array::c_style);  // the same array when it already is
  if (!a || a.dtype().byteorder() == '>')
    a = py::array(py::module_::import("numpy").attr("ascontiguousarray")(input, input.dtype().attr("newbyteorder")("=")));
  auto v = std::make_shared<Volume>();
  v->dims = {a.shape(2), a.shape(1), a.shape(0)};
  for (auto d : v->dims)
    if (d < 1) throw py::value_error("volume: every dimension must be at least 1");
  v->type = type;
  v->spacing = spacing;
  v->origin = origin;
  for (double s : spacing)
    if (!(s > 0) || !std::isfinite(s)) throw py::value_error("spacing: must be positive and finite");
  auto* owner = new py::object(a);
  std::shared_ptr<const void> keep(owner, [](const void* p) {
    py::gil_scoped_acquire gil;
    delete static_cast<const py::object*>(p);
  });
  v->bytes = VoxelBuffer::view(static_cast<const unsigned char*>(a.data()), static_cast<std::size_t>(a.nbytes()), std::move(keep));
  return v;
}

// The volume's values as a read-only numpy array [z, y, x] over its own bytes (no copy).
py::array volume_array(const std::shared_ptr<Volume>& v, py::object self) {
  const auto size = static_cast<py::ssize_t>(scalar_size(v->type));
  py::array a(dtype_of(v->type), {v->dims[2], v->dims[1], v->dims[0]}, {size * v->dims[0] * v->dims[1], size * v->dims[0], size},
              std::as_const(*v).bytes.data(), self);
  py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
  return a;
}

// A vector of fixed-size rows as a numpy array that owns it (no copy).
template <class T, std::size_t K>
py::array_t<T> rows_to_numpy(std::vector<std::array<T, K>>&& rows) {
  auto* heap = new std::vector<std::array<T, K>>(std::move(rows));
  py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<std::array<T, K>>*>(p); });
  return py::array_t<T>({static_cast<py::ssize_t>(heap->size()), static_cast<py::ssize_t>(K)},
                        {static_cast<py::ssize_t>(sizeof(std::array<T, K>)), static_cast<py::ssize_t>(sizeof(T))},
                        heap->empty() ? nullptr : heap->data()->data(), owner);
}

py::tuple mesh_tuple(Mesh&& m) {
  return py::make_tuple(rows_to_numpy(std::move(m.positions)), rows_to_numpy(std::move(m.triangles)), rows_to_numpy(std::move(m.normals)));
}

template <class T, std::size_t K>
std::vector<std::array<T, K>> numpy_to_rows(const py::array& input, const char* name) {
  auto a = py::array_t<T, py::array::c_style | py::array::forcecast>::ensure(input);
  if (!a || a.ndim() != 2 || a.shape(1) != static_cast<py::ssize_t>(K))
    throw py::value_error(std::string(name) + ": must be an array of shape (N, " + std::to_string(K) + ")");
  std::vector<std::array<T, K>> rows(static_cast<std::size_t>(a.shape(0)));
  if (!rows.empty()) std::memcpy(rows.data(), a.data(), rows.size() * sizeof(rows[0]));
  return rows;
}

py::object json_object(const std::string& text) { return py::module_::import("json").attr("loads")(text); }

// The Python face of a prepared grid.
struct Grid {
  std::shared_ptr<const PreparedGrid> grid;
  std::shared_ptr<const HierarchyQuery> query;  // bisection grids, made on first use

  const HierarchyQuery& hierarchy() {
    if (!query) query = std::make_shared<const HierarchyQuery>(grid);
    return *query;
  }
};

struct PyExtractor {
  std::shared_ptr<Extractor> extractor;
  ExtractStats last;
};

GridKind grid_kind(const std::string& s) {
  if (s == "bisection") return GridKind::bisection;
  if (s == "delaunay") return GridKind::delaunay;
  throw OptionError("grid", "must be 'bisection' or 'delaunay', got '" + s + "'");
}

ReduceMethod reduce_method(const std::string& s) {
  if (s == "reconstruction") return ReduceMethod::reconstruction;
  if (s == "structural") return ReduceMethod::structural;
  if (s == "both") return ReduceMethod::both;
  throw OptionError("method", "must be 'reconstruction', 'structural' or 'both', got '" + s + "'");
}

GradientOperator gradient_operator(const std::string& s) {
  if (s == "central") return GradientOperator::central;
  if (s == "canny") return GradientOperator::canny;
  throw OptionError("structural_gradient", "must be 'central' or 'canny', got '" + s + "'");
}

GradientMethod gradient_method(const std::string& s) {
  if (s == "auto") return GradientMethod::automatic;
  if (s == "lsq") return GradientMethod::least_squares;
  if (s == "central") return GradientMethod::central;
  throw OptionError("gradients", "must be 'auto', 'lsq' or 'central', got '" + s + "'");
}

// scikit-image's "values": the largest of the two voxels at the ends of each vertex's cube edge.
py::array_t<float> edge_maxima(const Volume& v, const Mesh& m) {
  py::array_t<float> out(static_cast<py::ssize_t>(m.vertex_count()));
  auto* o = out.mutable_data();
  for (std::size_t i = 0; i < m.vertex_count(); ++i) {
    double p[3];
    int axis = 0;
    double far = -1;
    for (int a = 0; a < 3; ++a) {
      p[a] = m.positions[i][a] / v.spacing[a];
      const double d = std::abs(p[a] - std::round(p[a]));
      if (d > far) far = d, axis = a;
    }
    std::int64_t lo[3], hi[3];
    for (int a = 0; a < 3; ++a) lo[a] = hi[a] = std::llround(p[a]);
    lo[axis] = static_cast<std::int64_t>(std::floor(p[axis]));
    hi[axis] = std::min(lo[axis] + 1, v.dims[axis] - 1);
    o[i] = static_cast<float>(std::max(v.at(lo[0], lo[1], lo[2]), v.at(hi[0], hi[1], hi[2])));
  }
  return out;
}

}  // namespace

PYBIND11_MODULE(adaptiso, m) {
  m.doc() = R"(adaptiso: adaptive iso-surface generation from 3D scalar volumes (after Lürig & Ertl).

    vol = adaptiso.read("scan.nii.gz")        # or adaptiso.Volume(array[z, y, x], spacing=(sx, sy, sz))
    grid = adaptiso.prepare(vol, max_error=0.02, relative=True)
    verts, faces, normals = grid.extract(iso=300.0)
    adaptiso.write_mesh("out.glb", verts, faces, normals)

Volumes are indexed array[z, y, x]; spacing and origin are (x, y, z); meshes are in world
coordinates (x, y, z), vertices float32 (N, 3), faces uint32 (M, 3), normals float32 (N, 3).)";
  m.attr("__version__") = ADAPTISO_VERSION;
  m.attr("DEFAULT_RELATIVE_ERROR") = kDefaultRelativeError;

  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const InputError& e) {  // OptionError included
      PyErr_SetString(PyExc_ValueError, e.what());
    }
  });

  py::class_<Volume, std::shared_ptr<Volume>>(m, "Volume", R"(A scalar volume on a regular grid.

Volume(array, spacing=(1, 1, 1), origin=(0, 0, 0)): array is indexed [z, y, x] (numpy's C order,
x fastest), of dtype uint8, int8, uint16, int16, uint32, int32, float32 or float64. A
C-contiguous array in native byte order is used in place (no copy; the volume keeps it alive and
never writes to it); any other array is copied. spacing and origin are (x, y, z).)")
      .def(py::init([](const py::array& array, Vec3 spacing, Vec3 origin) { return volume_from_array(array, spacing, origin); }),
           py::arg("array"), py::arg("spacing") = Vec3{1, 1, 1}, py::arg("origin") = Vec3{0, 0, 0})
      .def_property_readonly(
          "dims", [](const Volume& v) { return v.dims; }, "(nx, ny, nz)")
      .def_property_readonly(
          "shape", [](const Volume& v) { return py::make_tuple(v.dims[2], v.dims[1], v.dims[0]); }, "(nz, ny, nx), the array's shape")
      .def_property_readonly(
          "spacing", [](const Volume& v) { return v.spacing; }, "(x, y, z)")
      .def_property_readonly(
          "origin", [](const Volume& v) { return v.origin; }, "(x, y, z)")
      .def_property_readonly("dtype", [](const Volume& v) { return dtype_of(v.type); })
      .def_property_readonly(
          "is_view", [](const Volume& v) { return v.bytes.is_view(); }, "True when the volume reads a numpy array's memory in place")
      .def_property_readonly(
          "array", [](py::object self) { return volume_array(self.cast<std::shared_ptr<Volume>>(), self); },
          "The values as a read-only array [z, y, x] over the volume's memory (no copy)")
      .def(
          "range",
          [](const Volume& v) {
            py::gil_scoped_release release;
            const ValueRange r = value_range(v);
            return std::pair{r.min, r.max};
          },
          "(min, max) of the values")
      .def("__repr__", [](const Volume& v) {
        return "<adaptiso.Volume " + std::to_string(v.dims[0]) + "x" + std::to_string(v.dims[1]) + "x" + std::to_string(v.dims[2]) + " " +
               std::string(scalar_name(v.type)) + ">";
      });

  m.def(
      "read", [](const std::string& path) { return file_call([&] { return std::make_shared<Volume>(read_volume(path)); }); },
      py::arg("path"),
      "Reads a volume: .nrrd/.nhdr, .nii/.nii.gz, .mha/.mhd, .vti, .vtk, or a folder holding one DICOM series. OSError when it "
      "cannot be read.");

  py::class_<Grid>(m, "Grid", "A prepared tetrahedral grid with its extraction index (adaptiso.prepare or adaptiso.load).")
      .def(
          "extract",
          [](Grid& g, double iso, std::optional<double> max_error, bool relative) {
            Mesh mesh;
            {
              py::gil_scoped_release release;
              const auto& src = g.grid->grid.source;
              const double value = relative ? src.min + iso * (src.max - src.min) : iso;
              if (max_error) {
                const double e = relative ? *max_error * (src.max - src.min) : *max_error;
                mesh = g.hierarchy().extract(value, e);
              } else {
                Extractor ex(g.grid);
                ex.extract(value);
                mesh = ex.mesh();
              }
            }
            return mesh_tuple(std::move(mesh));
          },
          py::arg("iso"), py::arg("max_error") = py::none(), py::arg("relative") = false,
          R"(The iso-surface at iso: (vertices float32 (N, 3), faces uint32 (M, 3), normals float32 (N, 3)),
world coordinates, faces counter-clockwise seen from the side the normals point to (lower values).
max_error (bisection grids): a coarser error than the prepared one, from the grid's hierarchy.
relative: iso (and max_error) as fractions of the value range. Safe to call from several threads.)")
      .def(
          "extractor",
          [](Grid& g) {
            return PyExtractor{std::make_shared<Extractor>(g.grid), {}};
          },
          "An Extractor for browsing iso-values: each call after the first updates the previous surface.")
      .def(
          "coarsen",
          [](Grid& g, double max_error, int cell_floor) {
            py::gil_scoped_release release;
            return Grid{std::make_shared<const PreparedGrid>(cell_floor ? coarsen_floored(*g.grid, max_error, cell_floor)
                                                                        : coarsen(*g.grid, max_error)),
                        nullptr};
          },
          py::arg("max_error"), py::arg("cell_floor") = 0,
          R"(The bisection grid at a coarser error bound (data units), without the volume. cell_floor f > 0: no
tetrahedron finer than cubes of 2**f voxels (except along the volume's far faces), its guaranteed
error measured (stats["error_bound"]) rather than asked for: far fewer triangles on noisy data.)")
      .def(
          "save", [](Grid& g, const std::string& path) { file_call([&] { save_grid(*g.grid, path); }); }, py::arg("path"),
          "Writes the grid (.adg); OSError when it cannot be written.")
      .def_property_readonly(
          "stats", [](const Grid& g) { return json_object(to_json(g.grid->stats)); },
          "How the grid was made: the prepare statistics as a dict (the command line's --json)")
      .def_property_readonly("vertex_count", [](const Grid& g) { return g.grid->grid.vertex_count(); })
      .def_property_readonly("tetrahedron_count", [](const Grid& g) { return g.grid->grid.tet_count(); })
      .def_property_readonly("value_range",
                             [](const Grid& g) {
                               return std::pair{g.grid->grid.source.min, g.grid->grid.source.max};
                             })
      .def_property_readonly(
          "error_bound",
          [](const Grid& g) -> py::object {
            if (g.grid->stats.error_bound < 0) return py::none();
            return py::float_(g.grid->stats.error_bound);
          },
          "The guaranteed max-norm error of a bisection grid (data units); None for a Delaunay grid")
      .def("__repr__", [](const Grid& g) {
        return "<adaptiso.Grid " + g.grid->stats.grid + ": " + std::to_string(g.grid->grid.vertex_count()) + " vertices, " +
               std::to_string(g.grid->grid.tet_count()) + " tetrahedra>";
      });

  py::class_<PyExtractor>(m, "Extractor", "Incremental extraction over one grid (Grid.extractor()); not for use from two threads at once.")
      .def(
          "extract",
          [](PyExtractor& e, double iso) {
            Mesh copy;
            {
              py::gil_scoped_release release;
              e.last = e.extractor->extract(iso);
              copy = e.extractor->mesh();
            }
            return mesh_tuple(std::move(copy));
          },
          py::arg("iso"), "The surface at iso (vertices, faces, normals); small steps update the previous one.")
      .def_property_readonly("last_stats", [](const PyExtractor& e) {
        py::dict d;
        d["iso"] = e.last.iso;
        d["active"] = e.last.active;
        d["triangles"] = e.last.triangles;
        d["vertices"] = e.last.vertices;
        d["marched"] = e.last.marched;
        d["incremental"] = e.last.incremental;
        d["in_range"] = e.last.in_range;
        d["seconds"] = e.last.sweep_seconds + e.last.march_seconds;
        return d;
      });

  // prepare's and prepare_file's options, by the command line's names.
  auto prepare_options = [](const std::string& grid, std::optional<double> max_error, bool relative, double max_displacement,
                            const std::string& gradients, const std::string& method, double threshold,
                            const std::string& structural_gradient, double sigma, int kernel, std::uint32_t tree_depth, bool verify,
                            bool parallel_delaunay) {
    PrepareOptions o;
    o.grid = grid_kind(grid);
    o.max_error = max_error;
    o.relative = relative;
    o.max_displacement = max_displacement;
    o.gradients = gradient_method(gradients);
    o.method = reduce_method(method);
    o.threshold = threshold;
    o.structural_gradient = gradient_operator(structural_gradient);
    o.sigma = sigma;
    o.kernel = kernel;
    o.tree_depth = tree_depth;
    o.verify = verify;
    o.parallel_delaunay = parallel_delaunay;
    return o;
  };
  m.def(
      "prepare",
      [=](const Volume& v, const std::string& grid, std::optional<double> max_error, bool relative, double max_displacement,
          const std::string& gradients, const std::string& method, double threshold, const std::string& structural_gradient, double sigma,
          int kernel, std::uint32_t tree_depth, bool verify, bool parallel_delaunay) {
        const PrepareOptions o = prepare_options(grid, max_error, relative, max_displacement, gradients, method, threshold,
                                                 structural_gradient, sigma, kernel, tree_depth, verify, parallel_delaunay);
        py::gil_scoped_release release;
        return Grid{std::make_shared<const PreparedGrid>(prepare(v, o)), nullptr};
      },
      py::arg("volume"), py::kw_only(), py::arg("grid") = "bisection", py::arg("max_error") = py::none(), py::arg("relative") = false,
      py::arg("max_displacement") = 0.0, py::arg("gradients") = "auto", py::arg("method") = "reconstruction", py::arg("threshold") = 0.0,
      py::arg("structural_gradient") = "central", py::arg("sigma") = 1.0, py::arg("kernel") = 0, py::arg("tree_depth") = kDefaultTreeDepth,
      py::arg("verify") = false, py::arg("parallel_delaunay") = true,
      R"(Prepares a grid for extraction (the command line's `prepare`; the same option names).

grid: "bisection" (error guaranteed; default) or "delaunay" (the paper's). max_error: max-norm bound,
data units or a fraction of the value range with relative=True; None: DEFAULT_RELATIVE_ERROR of
the range. max_displacement (bisection): voxels an iso-surface may move, to first order.
gradients: "auto", "lsq" or "central". method, threshold, structural_gradient, sigma, kernel: the
Delaunay grid's reduction. verify: measure the error voxel by voxel. ValueError on a bad option.)");

  m.def(
      "prepare_file",
      [=](const Volume& v, const std::string& path, const std::string& grid, std::optional<double> max_error, bool relative,
          double max_displacement, const std::string& gradients, const std::string& method, double threshold,
          const std::string& structural_gradient, double sigma, int kernel, std::uint32_t tree_depth, bool verify, bool parallel_delaunay) {
        const PrepareOptions o = prepare_options(grid, max_error, relative, max_displacement, gradients, method, threshold,
                                                 structural_gradient, sigma, kernel, tree_depth, verify, parallel_delaunay);
        const PrepareStats stats = file_call([&] { return prepare_to_file(v, o, path); });
        return json_object(to_json(stats));
      },
      py::arg("volume"), py::arg("path"), py::kw_only(), py::arg("grid") = "bisection", py::arg("max_error") = py::none(),
      py::arg("relative") = false, py::arg("max_displacement") = 0.0, py::arg("gradients") = "auto", py::arg("method") = "reconstruction",
      py::arg("threshold") = 0.0, py::arg("structural_gradient") = "central", py::arg("sigma") = 1.0, py::arg("kernel") = 0,
      py::arg("tree_depth") = kDefaultTreeDepth, py::arg("verify") = false, py::arg("parallel_delaunay") = true,
      R"(prepare(volume, ...) and Grid.save(path) in one (the command line's `prepare`): the same file,
written as it is made, so the grid and its index are never in memory at once. Returns the
statistics (Grid.stats). ValueError on a bad option, OSError when the path cannot be written.)");

  m.def(
      "load",
      [](const std::string& path) {
        return file_call([&] { return Grid{std::make_shared<const PreparedGrid>(load_grid(path)), nullptr}; });
      },
      py::arg("path"), "Reads a grid file (.adg); OSError when it cannot be read.");

  m.def(
      "write_mesh",
      [](const std::string& path, const py::array& vertices, const py::array& faces, std::optional<py::array> normals) {
        Mesh mesh;
        mesh.positions = numpy_to_rows<float, 3>(vertices, "vertices");
        mesh.triangles = numpy_to_rows<std::uint32_t, 3>(faces, "faces");
        if (normals) mesh.normals = numpy_to_rows<float, 3>(*normals, "normals");
        if (!mesh.normals.empty() && mesh.normals.size() != mesh.positions.size())
          throw py::value_error("normals: must have one row per vertex");
        for (const auto& t : mesh.triangles)
          for (auto i : t)
            if (i >= mesh.positions.size()) throw py::value_error("faces: an index is out of range");
        file_call([&] { write_mesh(mesh, path); });
      },
      py::arg("path"), py::arg("vertices"), py::arg("faces"), py::arg("normals") = py::none(),
      "Writes a mesh by its extension: .ply, .obj, .stl or .glb. OSError when it cannot be written.");

  m.def(
      "marching_cubes",
      [](const py::array& array, std::optional<double> level, Vec3 spacing, const std::string& gradient_direction) {
        if (gradient_direction != "descent" && gradient_direction != "ascent")
          throw py::value_error("gradient_direction: must be 'descent' or 'ascent'");
        // scikit-image's spacing is in the array's index order [z, y, x]; the volume's is (x, y, z).
        auto v = volume_from_array(array, {spacing[2], spacing[1], spacing[0]}, {0, 0, 0});
        Mesh mesh;
        py::array_t<float> values;
        {
          py::gil_scoped_release release;
          const ValueRange r = value_range(*v);
          const double iso = level ? *level : 0.5 * (r.min + r.max);
          if (!(iso >= r.min && iso <= r.max)) {
            py::gil_scoped_acquire gil;
            throw py::value_error("level: must be within the volume's value range");
          }
          mesh = marching_cubes(*v, iso);
        }
        values = edge_maxima(*v, mesh);
        // To the array's index order (z, y, x): a reflection, so the winding turns too, and stays
        // counter-clockwise seen from the side the normals point to.
        const bool ascent = gradient_direction == "ascent";
        for (auto& p : mesh.positions) std::swap(p[0], p[2]);
        for (auto& n : mesh.normals) {
          std::swap(n[0], n[2]);
          if (ascent)
            for (auto& c : n) c = -c;
        }
        if (!ascent)
          for (auto& t : mesh.triangles) std::swap(t[1], t[2]);
        py::tuple t = mesh_tuple(std::move(mesh));
        return py::make_tuple(t[0], t[1], t[2], values);
      },
      py::arg("volume"), py::arg("level") = py::none(), py::kw_only(), py::arg("spacing") = Vec3{1, 1, 1},
      py::arg("gradient_direction") = "descent",
      R"(Full-resolution marching cubes with scikit-image's arguments and return order:
(verts, faces, normals, values). verts are in the array's index order scaled by spacing (both in
[z, y, x] order), as skimage.measure.marching_cubes returns them; level defaults to the middle of
the value range; normals point towards lower values ('descent') or higher ('ascent'); values are
the larger of the two voxels on each vertex's cube edge. The volume is used in place when it is
C-contiguous.)");

  m.def(
      "reduce",
      [](const Volume& v, std::optional<double> max_error, bool relative, const std::string& method, double threshold,
         const std::string& gradient, double sigma, int kernel) {
        ReduceOptions o;
        o.method = reduce_method(method);
        o.relative = relative;
        o.threshold = threshold;
        o.gradient = gradient_operator(gradient);
        o.sigma = sigma;
        o.kernel = kernel;
        std::vector<std::int64_t> kept;
        {
          py::gil_scoped_release release;
          const ValueRange r = value_range(v);
          o.max_error = max_error ? *max_error : default_max_error(r, relative);
          kept = reduce(v, r, o).kept;
        }
        py::array_t<std::int64_t> out({static_cast<py::ssize_t>(kept.size()), py::ssize_t{3}});
        auto* o3 = out.mutable_data();
        for (std::size_t i = 0; i < kept.size(); ++i) {
          const std::int64_t k = kept[i];
          o3[3 * i + 0] = k / (v.dims[0] * v.dims[1]);
          o3[3 * i + 1] = (k / v.dims[0]) % v.dims[1];
          o3[3 * i + 2] = k % v.dims[0];
        }
        return out;
      },
      py::arg("volume"), py::kw_only(), py::arg("max_error") = py::none(), py::arg("relative") = false,
      py::arg("method") = "reconstruction", py::arg("threshold") = 0.0, py::arg("gradient") = "central", py::arg("sigma") = 1.0,
      py::arg("kernel") = 0,
      R"(The paper's vertex reduction (§2.1) alone: the kept voxels as an int64 array (N, 3) of [z, y, x]
indices (array[tuple(kept.T)] gives their values), in ascending file order.)");
}
