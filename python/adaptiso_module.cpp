// The compiled half of the Python package `adaptiso` (adaptiso._core, pybind11): the library's
// pipeline where its users already work. python/adaptiso/__init__.py is the public face; it
// re-exports what is here and adds Mesh and scikit-image's marching_cubes signature.
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
#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <future>
#include <limits>
#include <memory>
#include <mutex>
#include <numeric>
#include <optional>
#include <sstream>
#include <string>
#include <type_traits>
#include <utility>

#include "adaptiso/error.hpp"
#include "adaptiso/extractor.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/marching_cubes.hpp"
#include "adaptiso/memory.hpp"
#include "adaptiso/mesh_io.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/prepare_to_file.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/simplify.hpp"
#include "adaptiso/version.hpp"
#include "adaptiso/volume_io.hpp"
#include "file_errors.hpp"
#include "prepare_over_comm.hpp"

namespace py = pybind11;
using namespace adaptiso;

namespace {

using python::file_errors;

// Runs f with the GIL released; InputError becomes OSError (file operations, file_errors.hpp).
template <class F>
auto file_call(F&& f) {
  return file_errors([&] {
    py::gil_scoped_release release;
    return f();
  });
}

// Runs work(cancel) on a worker thread while the calling thread, without the GIL, looks for a
// signal every 50 ms, so a long extraction answers Ctrl-C (and Jupyter's interrupt): Python runs
// its signal handlers only on the main thread and with the GIL, never inside a C++ call. A handler
// that raises (KeyboardInterrupt) raises the work's cancel flag (HierarchyQuery's extract and
// extract_within, Extractor::extract), the work stops with ExtractCancelled within a stage's part,
// and the handler's exception is raised here. Called with the GIL released.
template <class F>
void interruptible(F&& work) {
  std::atomic<bool> cancel{false};
  auto task = std::async(std::launch::async, [&] { work(&cancel); });
  while (task.wait_for(std::chrono::milliseconds(50)) != std::future_status::ready) {
    py::gil_scoped_acquire gil;
    if (PyErr_CheckSignals() == 0) continue;
    cancel = true;
    {
      py::gil_scoped_release release;  // the handler's exception stays set on this thread
      task.wait();
    }
    try {
      task.get();
    } catch (...) {  // ExtractCancelled, as asked; any other failure loses to the signal too
    }
    throw py::error_already_set();
  }
  task.get();  // the work's own exception, if any
}

// A path argument: str, bytes or os.PathLike, in the file system's encoding. A NUL would cut the
// name short at the C library, so it is refused as Python's own open() refuses it.
std::string path_arg(const py::handle& path, const char* name = "path") {
  py::module_ os = py::module_::import("os");
  py::object p;
  try {
    p = os.attr("fspath")(path);
  } catch (py::error_already_set&) {
    throw py::type_error(std::string(name) + ": must be a str, bytes or os.PathLike object, not " +
                         py::str(py::type::handle_of(path).attr("__name__")).cast<std::string>());
  }
  const std::string bytes = os.attr("fsencode")(p).cast<std::string>();
  if (bytes.find('\0') != std::string::npos) throw py::value_error(std::string(name) + ": embedded null character");
  return bytes;
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

// Spacing and origin as the rest of the library can use them: meshes are float32, so every voxel's
// world coordinate must stay finite there and neighbours distinct from zero. 1e-30 to 1e30 covers
// any unit from femtometres to light years with room; NaN, Inf, zero and denormals are refused.
constexpr double kSpacingMin = 1e-30, kSpacingMax = 1e30, kCoordinateMax = 1e36;

std::string number(double x) {
  std::ostringstream s;
  s << x;
  return s.str();
}

void check_geometry(const Vec3& spacing, const Vec3& origin, const Dims& dims) {
  for (int a = 0; a < 3; ++a)
    if (!(spacing[a] >= kSpacingMin && spacing[a] <= kSpacingMax))
      throw OptionError("spacing", "must be a positive number from 1e-30 to 1e30, got " + number(spacing[a]));
  for (int a = 0; a < 3; ++a)
    if (!(std::abs(origin[a]) <= kSpacingMax))
      throw OptionError("origin", "must be a finite number within ±1e30, got " + number(origin[a]));
  for (int a = 0; a < 3; ++a)
    if (std::abs(origin[a]) + spacing[a] * static_cast<double>(dims[a] - 1) > kCoordinateMax)
      throw OptionError("spacing", "the volume would reach beyond 1e36 along axis " + std::to_string(a) + " (spacing " +
                                       number(spacing[a]) + " × " + std::to_string(dims[a] - 1) + " voxels)");
}

// An array-like as a numpy array without a copy where one can be avoided: ndarrays as they are
// (memmaps included: nothing is read here), buffer-protocol objects and objects with __array__
// through numpy.asarray.
py::array as_array(const py::handle& input) {
  if (py::isinstance<py::array>(input)) return py::reinterpret_borrow<py::array>(input);
  py::object a;
  try {
    a = py::module_::import("numpy").attr("asarray")(input);
  } catch (py::error_already_set&) {
    throw py::type_error("volume: expected an array (numpy, the buffer protocol or __array__), got " +
                         py::str(py::type::handle_of(input).attr("__name__")).cast<std::string>());
  }
  if (!py::isinstance<py::array>(a) || a.attr("dtype").attr("kind").cast<std::string>() == "O")
    throw py::type_error("volume: expected a numeric array, got " +
                         py::str(py::type::handle_of(input).attr("__name__")).cast<std::string>());
  return py::reinterpret_borrow<py::array>(a);
}

// A numpy array of shape (nz, ny, nx) as a Volume: a view of its memory when it is C-contiguous
// and in native byte order, a copy otherwise. The view holds a reference to the array, released
// with the GIL held whichever thread drops the Volume last. NaN and Inf are refused with the
// readers' message (check_finite: how many, and the first voxel as x,y,z).
std::shared_ptr<Volume> volume_from_array(const py::array& input, const Vec3& spacing, const Vec3& origin, bool check_values = true) {
  if (input.ndim() != 3) throw py::value_error("volume: the array must have 3 dimensions [z, y, x], got " + std::to_string(input.ndim()));
  const ScalarType type = scalar_type_of(input.dtype());
  py::array a = py::array::ensure(input, py::array::c_style);  // the same array when it already is
  if (!a || a.dtype().byteorder() == '>')
    a = py::array(py::module_::import("numpy").attr("ascontiguousarray")(input, input.dtype().attr("newbyteorder")("=")));
  auto v = std::make_shared<Volume>();
  v->dims = {a.shape(2), a.shape(1), a.shape(0)};
  for (auto d : v->dims)
    if (d < 1) throw py::value_error("volume: every dimension must be at least 1");
  check_geometry(spacing, origin, v->dims);
  v->type = type;
  v->spacing = spacing;
  v->origin = origin;
  auto* owner = new py::object(a);
  std::shared_ptr<const void> keep(owner, [](const void* p) {
    py::gil_scoped_acquire gil;
    delete static_cast<const py::object*>(p);
  });
  v->bytes = VoxelBuffer::view(static_cast<const unsigned char*>(a.data()), static_cast<std::size_t>(a.nbytes()), std::move(keep));
  if (check_values) {
    py::gil_scoped_release release;
    check_finite(*v, "volume");
  }
  return v;
}

// value_range and check_finite in one parallel pass (marching_cubes reads the volume once before
// marching). x - x is 0 for every finite x and NaN for NaN and ±Inf, so one sum per block tells
// whether all are finite; when not, check_finite gives the readers' message.
ValueRange finite_range(const Volume& v) {
  bool finite = true;
  const ValueRange r = visit_values(v, [&]<class T>(std::span<const T> vals) {
    struct Acc {
      T lo, hi, residue;
    };
    const Acc a = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, vals.size(), 1 << 16), Acc{vals[0], vals[0], T{}},
        [&](const tbb::blocked_range<std::size_t>& b, Acc acc) {
          for (std::size_t i = b.begin(); i < b.end(); ++i) {
            acc.lo = std::min(acc.lo, vals[i]);
            acc.hi = std::max(acc.hi, vals[i]);
            if constexpr (std::is_floating_point_v<T>) acc.residue += vals[i] - vals[i];
          }
          return acc;
        },
        [](Acc x, Acc y) {
          return Acc{std::min(x.lo, y.lo), std::max(x.hi, y.hi), T(x.residue + y.residue)};
        });
    if constexpr (std::is_floating_point_v<T>) finite = a.residue == 0 && std::isfinite(a.lo) && std::isfinite(a.hi);
    return ValueRange{static_cast<double>(a.lo), static_cast<double>(a.hi)};
  });
  if (!finite) check_finite(v, "volume");
  return r;
}

// Volume(...) from an array-like or an image object (nibabel): the latter's geometry comes from
// adaptiso._inputs.image_geometry, as adaptiso.read takes it from the same file. Explicit spacing
// or origin win over the image's.
std::shared_ptr<Volume> make_volume_from(const py::object& input, std::optional<Vec3> spacing, std::optional<Vec3> origin) {
  py::object image = py::module_::import("adaptiso._inputs").attr("image_geometry")(input);
  if (image.is_none()) return volume_from_array(as_array(input), spacing.value_or(Vec3{1, 1, 1}), origin.value_or(Vec3{0, 0, 0}));
  auto g = image.cast<py::tuple>();  // (array [i, j, k], spacing, origin, direction 3×3 row-major)
  py::array ijk = as_array(g[0]);
  py::array zyx = py::reinterpret_borrow<py::array>(ijk.attr("T"));  // a view; C-contiguous when the file's order is
  auto v = volume_from_array(zyx, spacing.value_or(g[1].cast<Vec3>()), origin.value_or(g[2].cast<Vec3>()));
  v->direction = g[3].cast<std::array<double, 9>>();
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

// A vector of fixed-size rows as a numpy array that owns it (no copy); As reinterprets the
// element type (uint32 faces as scikit-image's int32, the same bits below 2^31).
template <class As = void, class T, std::size_t K>
auto rows_to_numpy(std::vector<std::array<T, K>>&& rows) {
  using E = std::conditional_t<std::is_void_v<As>, T, As>;
  static_assert(sizeof(E) == sizeof(T));
  auto* heap = new std::vector<std::array<T, K>>(std::move(rows));
  py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<std::array<T, K>>*>(p); });
  return py::array_t<E>({static_cast<py::ssize_t>(heap->size()), static_cast<py::ssize_t>(K)},
                        {static_cast<py::ssize_t>(sizeof(std::array<T, K>)), static_cast<py::ssize_t>(sizeof(T))},
                        heap->empty() ? nullptr : reinterpret_cast<const E*>(heap->data()->data()), owner);
}

py::array_t<float> vector_to_numpy(std::vector<float>&& values) {
  auto* heap = new std::vector<float>(std::move(values));
  py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<float>*>(p); });
  return py::array_t<float>({static_cast<py::ssize_t>(heap->size())}, {static_cast<py::ssize_t>(sizeof(float))},
                            heap->empty() ? nullptr : heap->data(), owner);
}

// adaptiso.Mesh (python/adaptiso/_mesh.py) around the library's mesh, world coordinates (x, y, z).
py::object make_mesh(Mesh&& m, py::dict stats) {
  py::object cls = py::module_::import("adaptiso._mesh").attr("Mesh");
  return cls(rows_to_numpy(std::move(m.positions)), rows_to_numpy(std::move(m.triangles)), rows_to_numpy(std::move(m.normals)), py::none(),
             py::arg("stats") = stats, py::arg("axes") = "xyz");
}

template <class T, std::size_t K>
std::vector<std::array<T, K>> numpy_to_rows(const py::handle& input, const char* name) {
  auto a = py::array_t<T, py::array::c_style | py::array::forcecast>::ensure(input);
  if (!a || a.ndim() != 2 || a.shape(1) != static_cast<py::ssize_t>(K)) {
    PyErr_Clear();
    throw py::value_error(std::string(name) + ": must be an array of shape (N, " + std::to_string(K) + ")");
  }
  std::vector<std::array<T, K>> rows(static_cast<std::size_t>(a.shape(0)));
  if (!rows.empty()) std::memcpy(rows.data(), a.data(), rows.size() * sizeof(rows[0]));
  return rows;
}

// A mesh from Python's arrays (write_mesh, simplify), checked: ValueError for a wrong shape, normals
// that are not one per vertex, or a face index out of range.
Mesh mesh_from_numpy(const py::object& vertices, const py::object& faces, const py::object& normals) {
  Mesh mesh;
  mesh.positions = numpy_to_rows<float, 3>(vertices, "vertices");
  mesh.triangles = numpy_to_rows<std::uint32_t, 3>(faces, "faces");
  if (!normals.is_none()) mesh.normals = numpy_to_rows<float, 3>(normals, "normals");
  if (!mesh.normals.empty() && mesh.normals.size() != mesh.positions.size()) throw py::value_error("normals: must have one row per vertex");
  for (const auto& t : mesh.triangles)
    for (auto i : t)
      if (i >= mesh.positions.size()) throw py::value_error("faces: an index is out of range");
  return mesh;
}

py::object json_object(const std::string& text) { return py::module_::import("json").attr("loads")(text); }

// The Python face of a prepared grid. adaptiso.load reads a bisection grid's vertices and hierarchy
// only (GridParts::hierarchy_or_all): they are all that extract(distance=…) and
// extract(max_error=…) walk, and they load in about a third of the time and memory (the CT bunny's
// 1.8 GB grid). The routes that need the tetrahedra (extract(iso), extractor(), coarsen, save) load
// the whole file on first use, from the file as it was: the Grid keeps it open, so that a file
// since replaced or deleted still gives the grid that was loaded, not another.
class Grid {
public:
  explicit Grid(std::shared_ptr<const PreparedGrid> g) : grid_(std::move(g)) {}
  // A grid prepared without its extraction index (prepare_without_index): whole() builds it the
  // first time a route needs it (extractor()); whole surfaces scan, the hierarchy's queries need
  // none, and saving leaves it out.
  struct Unindexed {};
  Grid(std::shared_ptr<PreparedGrid> g, Unindexed) : grid_(g), unindexed_(std::move(g)) {}
  // A file loaded without its tetrahedra: the rest comes from it when a route needs them.
  Grid(std::shared_ptr<const PreparedGrid> g, std::unique_ptr<OpenGridFile> file) : grid_(std::move(g)), file_(std::move(file)) {}

  // What is in memory: the file's metadata, statistics, vertices and hierarchy, and its
  // tetrahedra unless loaded in part.
  std::shared_ptr<const PreparedGrid> loaded() const {
    std::lock_guard lock(mutex_);
    return grid_;
  }
  // The grid with its tetrahedra and index, read now if it was loaded in part, the index built
  // now if it was prepared without. Call without the GIL.
  std::shared_ptr<const PreparedGrid> whole() {
    std::lock_guard loading(load_mutex_);  // two threads' first calls read the file once
    if (std::lock_guard lock(mutex_); unindexed_) return add_index_once();
    if (auto g = loaded(); !loaded_in_part(*g)) return g;
    auto g = std::make_shared<const PreparedGrid>(file_->load(GridParts::all));
    std::lock_guard lock(mutex_);
    grid_ = g;
    query_.reset();  // the next query walks the whole grid's copy; the vertices-only one is freed
    tetrahedra_.reset();
    file_.reset();
    return g;
  }
  // The grid with its tetrahedra, with its index or not: what is in memory, or, loaded in part,
  // its tetrahedra read once without building the index, which a whole surface does not need (a
  // scan finds its tetrahedra as fast as a fresh sweep; the CT bunny's first extract(iso) 3 s
  // instead of 5-7). Call without the GIL.
  std::shared_ptr<const PreparedGrid> with_tetrahedra() {
    std::lock_guard loading(load_mutex_);
    if (auto g = loaded(); !loaded_in_part(*g)) return g;
    if (std::lock_guard lock(mutex_); tetrahedra_) return tetrahedra_;
    auto g = std::make_shared<const PreparedGrid>(file_->load(GridParts::tetrahedra));  // the others' queries go on meanwhile
    std::lock_guard lock(mutex_);
    tetrahedra_ = g;
    return g;
  }
  // The grid with its tetrahedra, for writing elsewhere: what is in memory, or, loaded in part, the
  // tetrahedra read from the file for this call only, without the index (not built: saving leaves
  // it out, and building it took about 2.5 s of the CT bunny's 4 s). Call without the GIL.
  std::shared_ptr<const PreparedGrid> for_writing() {
    std::lock_guard loading(load_mutex_);
    if (auto g = loaded(); !loaded_in_part(*g)) return g;
    if (std::lock_guard lock(mutex_); tetrahedra_) return tetrahedra_;
    return std::make_shared<const PreparedGrid>(file_->load(GridParts::tetrahedra));
  }
  // The hierarchy's queries over what is loaded (made on first use; bisection grids).
  std::shared_ptr<const HierarchyQuery> hierarchy() {
    std::lock_guard lock(mutex_);
    if (!query_) query_ = std::make_shared<const HierarchyQuery>(grid_);
    return query_;
  }

  std::optional<py::dict> bricks;  // prepared in bricks or over ranks: what they did (stats["bricks"])

private:
  // With mutex_ held: the index built into the grid itself when nothing else holds it (the
  // hierarchy's query made of it is dropped, to be made again on first use), otherwise, while
  // another thread's call holds the grid, into a copy that replaces it. A holder other than the
  // Grid can only be had through mutex_, so a count of two (grid_ and unindexed_) means none.
  std::shared_ptr<const PreparedGrid> add_index_once() {
    if (query_.use_count() == 1) query_.reset();
    if (grid_.use_count() == 2) {
      add_index(*unindexed_);
    } else {
      auto copy = std::make_shared<PreparedGrid>(*unindexed_);
      add_index(*copy);
      grid_ = std::move(copy);
      query_.reset();
    }
    unindexed_.reset();
    return grid_;
  }

  mutable std::mutex mutex_;  // grid_ and query_: two threads' first extract(max_error=...) make one query
  std::mutex load_mutex_;
  std::shared_ptr<const PreparedGrid> grid_;
  std::shared_ptr<const HierarchyQuery> query_;
  std::shared_ptr<const PreparedGrid> tetrahedra_;  // loaded in part: the tetrahedra without the index, once read
  std::shared_ptr<PreparedGrid> unindexed_;         // grid_ while it is without its index (prepared here)
  std::unique_ptr<OpenGridFile> file_;              // the file loaded in part, until whole() reads the rest
};

// An Extractor keeps the previous surface to update it: one call at a time, the others wait (the
// mutex is taken with the GIL released, so a waiting thread does not hold up the rest of Python).
struct PyExtractor {
  std::shared_ptr<Extractor> extractor;
  std::shared_ptr<const PreparedGrid> grid;  // for the value range of relative iso-values
  ExtractStats last;
  std::mutex mutex;
};

// Type.__new__(Type) makes an instance without running __init__, and pybind11 would hand its
// methods uninitialised memory (it allocates the value lazily, unconstructed). Every entry point
// takes its adaptiso objects through this check instead, which looks at whether the holder was
// constructed: such an object raises TypeError rather than crashing the interpreter.
template <class T>
T& initialised(py::handle obj, const char* type, const char* how) {
  if (!py::isinstance<T>(obj))
    throw py::type_error(std::string("expected an adaptiso.") + type + ", got " +
                         py::str(py::type::handle_of(obj).attr("__name__")).cast<std::string>());
  auto* inst = reinterpret_cast<py::detail::instance*>(obj.ptr());
  auto v_h = inst->get_value_and_holder(py::detail::get_type_info(typeid(T)), false);
  if (!v_h || !v_h.holder_constructed() || !v_h.value_ptr())
    throw py::type_error(std::string("adaptiso.") + type + ": not initialised (" + how + ")");
  return *static_cast<T*>(v_h.value_ptr());
}
// adaptiso.load: a bisection grid without its tetrahedra, the file kept open for them (see Grid).
// `share`: loaded by every process of a communicator at once, the checks shared out.
std::unique_ptr<Grid> load_in_part(const std::string& path, ShareTransport* share = nullptr) {
  auto file = std::make_unique<OpenGridFile>(path, share);  // opened first: the rest comes from the same file
  auto g = std::make_shared<const PreparedGrid>(file->load(GridParts::hierarchy_or_all, {}, share));
  if (!loaded_in_part(*g)) return std::make_unique<Grid>(std::move(g));  // no hierarchy: loaded whole, the file closed
  return std::make_unique<Grid>(std::move(g), std::move(file));
}

Grid& grid_of(py::handle h) { return initialised<Grid>(h, "Grid", "get one from adaptiso.prepare or adaptiso.load"); }
PyExtractor& extractor_of(py::handle h) { return initialised<PyExtractor>(h, "Extractor", "get one from Grid.extractor()"); }
const Volume& volume_of(py::handle h) { return initialised<Volume>(h, "Volume", "make one with adaptiso.Volume(array) or adaptiso.read"); }

// prepare's volume: a Volume, or a file's path (str, bytes or os.PathLike).
python::PrepareInput prepare_input(py::handle volume, PrepareOptions options) {
  python::PrepareInput in;
  in.options = std::move(options);
  if (py::isinstance<py::str>(volume) || py::isinstance<py::bytes>(volume) || py::hasattr(volume, "__fspath__"))
    in.options.source_name = in.path = path_arg(volume, "volume");  // recorded in the grid, as the command line does
  else
    in.volume = &volume_of(volume);
  return in;
}

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

// The reduction's options by the command line's names, for prepare (the Delaunay grid's) and reduce
// alike; the error bound is each caller's.
ReduceOptions reduce_options(const std::string& method, double threshold, const std::string& gradient, double sigma, int kernel,
                             bool relative) {
  ReduceOptions o;
  o.method = reduce_method(method);
  o.threshold = threshold;
  o.gradient = gradient_operator(gradient);
  o.sigma = sigma;
  o.kernel = kernel;
  o.relative = relative;
  return o;
}

GradientMethod gradient_method(const std::string& s) {
  if (s == "auto") return GradientMethod::automatic;
  if (s == "lsq") return GradientMethod::least_squares;
  if (s == "central") return GradientMethod::central;
  throw OptionError("gradients", "must be 'auto', 'lsq' or 'central', got '" + s + "'");
}

py::dict extract_stats(const ExtractStats& s) { return py::module_::import("json").attr("loads")(to_json(s)); }

py::dict distance_stats(const DistanceQueryStats& s) {
  py::dict d;
  d["iso"] = s.iso;
  d["in_range"] = s.in_range;
  d["triangles"] = s.triangles;
  d["vertices"] = s.vertices;
  d["distance_voxels"] = s.distance;
  d["marched_tetrahedra"] = s.tetrahedra;
  d["tested_tetrahedra"] = s.tested;
  d["split_diamonds"] = s.refined;
  d["closure_diamonds"] = s.closure;
  d["visited_tetrahedra"] = s.visited;
  d["seconds"] = s.refine_seconds + s.walk_seconds + s.march_seconds + s.collapse_seconds;
  d["refine_seconds"] = s.refine_seconds;
  d["walk_seconds"] = s.walk_seconds;
  d["march_seconds"] = s.march_seconds;
  d["specks_dropped"] = s.specks;
  d["speck_triangles"] = s.speck_triangles;
  d["min_piece_voxels"] = s.min_piece;
  d["collapsed_edges"] = s.collapsed;
  d["collapse_rounds"] = s.collapse_rounds;
  d["collapses_probed"] = s.collapses_probed;
  d["collapses_failed"] = s.collapses_failed;
  d["collapse_seconds"] = s.collapse_seconds;
  return d;
}

py::dict query_stats(const HierarchyQueryStats& s) {
  py::dict d;
  d["iso"] = s.iso;
  d["in_range"] = s.in_range;
  d["triangles"] = s.triangles;
  d["vertices"] = s.vertices;
  d["max_error"] = s.max_error;
  d["error_bound"] = s.error_bound;
  d["marched_tetrahedra"] = s.tetrahedra;
  d["visited_tetrahedra"] = s.visited;
  d["seconds"] = s.walk_seconds + s.march_seconds;
  d["walk_seconds"] = s.walk_seconds;
  d["march_seconds"] = s.march_seconds;
  return d;
}

// scikit-image's remove_degenerate_faces, without its order dependence: faces with two vertices
// at the same position are dropped, and the vertices they join are merged into the lowest index
// (union-find, so chains of such faces merge completely); the merged-away vertices go.
void remove_degenerate(Mesh& m, std::vector<float>& values) {
  const std::size_t n = m.positions.size();
  std::vector<std::uint32_t> parent(n);
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](std::uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  auto unite = [&](std::uint32_t a, std::uint32_t b) {
    a = find(a), b = find(b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  };
  std::vector<std::array<std::uint32_t, 3>> kept;
  kept.reserve(m.triangles.size());
  for (const auto& t : m.triangles) {
    bool degenerate = false;
    for (int e = 0; e < 3; ++e) {
      const auto a = t[e], b = t[(e + 1) % 3];
      if (m.positions[a] == m.positions[b]) unite(a, b), degenerate = true;
    }
    if (!degenerate) kept.push_back(t);
  }
  std::vector<std::uint32_t> number(n);
  std::uint32_t next = 0;
  for (std::uint32_t v = 0; v < n; ++v) {
    if (find(v) != v) continue;
    number[v] = next;
    m.positions[next] = m.positions[v];
    m.normals[next] = m.normals[v];
    values[next] = values[v];
    ++next;
  }
  m.positions.resize(next), m.normals.resize(next), values.resize(next);
  for (auto& t : kept)
    for (auto& i : t) i = number[find(i)];
  m.triangles = std::move(kept);
}

}  // namespace

PYBIND11_MODULE(_core, m) {
  m.doc() = "The compiled part of adaptiso; use the package `adaptiso`, which re-exports it.";
  m.attr("__version__") = ADAPTISO_VERSION;
  m.attr("DEFAULT_RELATIVE_ERROR") = kDefaultRelativeError;

  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const InputError& e) {  // OptionError included
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const python::FileError& e) {  // prepare's volume file
      PyErr_SetString(PyExc_OSError, e.what());
    }
  });

  py::class_<Volume, std::shared_ptr<Volume>>(m, "Volume", R"(A scalar volume on a regular grid.

Volume(array, spacing=None, origin=None)

array: indexed [z, y, x] (numpy's C order, x fastest), of dtype uint8, int8, uint16, int16,
uint32, int32, float32 or float64: a numpy array (memmaps included), any object with the buffer
protocol or __array__, or a nibabel image (its data in the file's order, spacing, origin and
orientation from its sform/qform as adaptiso.read takes them). A C-contiguous array in native
byte order is used in place (no copy; the volume keeps it alive and never writes to it), so is a
NIfTI file's memmap; any other array is copied once. spacing and origin are (x, y, z); default
(1, 1, 1) and (0, 0, 0), or the image's.

ValueError: NaN or Inf values (how many, and the first as voxel x,y,z), a spacing outside 1e-30 to
1e30, a non-finite origin, not 3 dimensions or an unsupported dtype.)")
      .def(py::init(&make_volume_from), py::arg("array"), py::arg("spacing") = py::none(), py::arg("origin") = py::none())
      .def_property_readonly(
          "dims", [](py::handle self) { return volume_of(self).dims; }, "(nx, ny, nz)")
      .def_property_readonly(
          "shape",
          [](py::handle self) {
            const Volume& v = volume_of(self);
            return py::make_tuple(v.dims[2], v.dims[1], v.dims[0]);
          },
          "(nz, ny, nx), the array's shape")
      .def_property_readonly(
          "spacing", [](py::handle self) { return volume_of(self).spacing; }, "Voxel size (x, y, z)")
      .def_property_readonly(
          "origin", [](py::handle self) { return volume_of(self).origin; }, "World position of voxel (0, 0, 0), (x, y, z)")
      .def_property_readonly(
          "direction",
          [](py::handle self) {
            const auto& d = volume_of(self).direction;
            return py::make_tuple(py::make_tuple(d[0], d[1], d[2]), py::make_tuple(d[3], d[4], d[5]), py::make_tuple(d[6], d[7], d[8]));
          },
          "3×3 rows; column a is the world direction of index axis a (x, y, z)")
      .def_property_readonly(
          "dtype", [](py::handle self) { return dtype_of(volume_of(self).type); }, "The values' numpy dtype")
      .def_property_readonly(
          "is_view", [](py::handle self) { return volume_of(self).bytes.is_view(); },
          "True when the volume reads a numpy array's memory in place")
      .def_property_readonly(
          "array",
          [](py::object self) {
            volume_of(self);
            return volume_array(self.cast<std::shared_ptr<Volume>>(), self);
          },
          "The values as a read-only array [z, y, x] over the volume's memory (no copy)")
      .def(
          "range",
          [](py::handle self) {
            const Volume& v = volume_of(self);
            py::gil_scoped_release release;
            const ValueRange r = value_range(v);
            return std::pair{r.min, r.max};
          },
          "(min, max) of the values")
      .def("__repr__", [](py::handle self) {
        const Volume& v = volume_of(self);
        return "<adaptiso.Volume " + std::to_string(v.dims[0]) + "x" + std::to_string(v.dims[1]) + "x" + std::to_string(v.dims[2]) + " " +
               std::string(scalar_name(v.type)) + ">";
      });

  m.def(
      "read",
      [](const py::object& path) {
        const std::string p = path_arg(path);
        return file_call([&] { return std::make_shared<Volume>(read_volume(p)); });
      },
      py::arg("path"),
      "read(path) -> Volume\n\nReads a volume: .nrrd/.nhdr, .nii/.nii.gz, .mha/.mhd, .vti, .vtk, or a folder holding one DICOM series. "
      "path: str, bytes or os.PathLike. OSError when it cannot be read.");

  py::class_<Grid>(
      m, "Grid",
      "A prepared tetrahedral grid (adaptiso.prepare or adaptiso.load); its extraction index is built when extractor() first needs it.")
      .def(
          "extract",
          [](py::handle self, double iso, std::optional<double> max_error, bool relative, std::optional<double> distance,
             std::optional<int> collapse, const py::object& comm, std::optional<double> min_piece) {
            Grid& g = grid_of(self);
            if (max_error && distance) throw py::value_error("max_error and distance: give one of them");
            if (collapse && !distance) throw py::value_error("collapse needs distance");
            if (min_piece && !distance) throw py::value_error("min_piece needs distance");
            if (!comm.is_none() && !distance) throw py::value_error("comm needs distance: only surfaces at a distance are made together");
            const auto together = python::comm_transport(comm);  // null for one process
            Mesh mesh;
            std::optional<HierarchyQueryStats> query;
            std::optional<DistanceQueryStats> within;
            std::optional<ExtractStats> full;
            {
              py::gil_scoped_release release;
              const auto loaded = g.loaded();
              const ValueRange range{loaded->grid.source.min, loaded->grid.source.max};
              const double value = relative ? from_fraction(range, iso, FractionOf::value, "iso") : iso;
              if (distance) {
                within.emplace();
                const auto hierarchy = g.hierarchy();
                const int rounds = collapse.value_or(kDefaultCollapseRounds);
                if (together)  // collective: not cancelled on one process alone
                  mesh = hierarchy->extract_within(*together, value, *distance, &*within, rounds, min_piece);
                else
                  interruptible([&](const std::atomic<bool>* cancel) {
                    mesh = hierarchy->extract_within(value, *distance, &*within, rounds, cancel, {}, min_piece);
                  });
              } else if (max_error) {
                const double e = relative ? from_fraction(range, *max_error, FractionOf::width, "max_error") : *max_error;
                query.emplace();
                const auto hierarchy = g.hierarchy();
                interruptible([&](const std::atomic<bool>* cancel) { mesh = hierarchy->extract(value, e, 0, &*query, nullptr, cancel); });
              } else if (const auto grid = file_errors([&] { return g.with_tetrahedra(); }); !grid->index.nodes.empty()) {
                Extractor ex(grid);
                interruptible([&](const std::atomic<bool>* cancel) { full = ex.extract(value, cancel); });
                mesh = ex.mesh();
              } else {
                interruptible([&](const std::atomic<bool>* cancel) { full = extract_scanned(grid->grid, value, mesh, cancel); });
              }
            }
            return make_mesh(std::move(mesh), within ? distance_stats(*within) : query ? query_stats(*query) : extract_stats(*full));
          },
          py::arg("iso"), py::arg("max_error") = py::none(), py::arg("relative") = false, py::arg("distance") = py::none(),
          py::arg("collapse") = py::none(), py::arg("comm") = py::none(), py::arg("min_piece") = py::none(),
          R"(extract(iso, max_error=None, relative=False, distance=None, collapse=None, comm=None, min_piece=None) -> Mesh

The iso-surface at iso as a Mesh, which unpacks as (vertices float32 (N, 3), faces uint32 (M, 3),
normals float32 (N, 3)): world coordinates (x, y, z), faces counter-clockwise seen from the side
the normals point to (lower values); Mesh.stats holds the command line's figures.
max_error (bisection grids): a coarser error than the prepared one, from the grid's hierarchy.
distance (bisection grids): the fewest triangles within about this many voxels (of the smallest
spacing) of the grid's surface, refined where this surface needs it; every vertex is one of the
full surface's (HierarchyQuery::extract_within). Pieces smaller than min_piece voxels (bounding
box's diagonal under it; default the distance) are dropped as specks: stats["specks_dropped"],
stats["speck_triangles"]; min_piece=0 keeps every piece (a small lesion, say).
collapse (with distance): up to this many rounds of edge collapses after the march, each checked
by the same tests (a fifth to a quarter fewer triangles a round on the CT and MR scans measured;
a round removing under a sixteenth is the last; default 8, 2 is faster); 0 keeps every triangle
inside its tetrahedron. ValueError outside 0..16.
comm (with distance): an mpi4py communicator whose every process calls extract with the same
arguments on the same grid: they make the surface together (the refinement, the walk and the
collapses' probes shared out) and each gets the mesh one process makes, byte for byte (the CT
bunny over 2 processes, one thread each: about 1.5x one's speed). Collective: calls with one
communicator are made in the same order on every process, one at a time (their messages would
mix), and are not stopped by Ctrl-C; a process that dies mid-call leaves the others waiting (run
under `python -m mpi4py`, which then stops the job). A process asking for another surface, or
holding a grid of another shape, makes every process raise ValueError.
relative: iso (and max_error) as fractions of the value range. Safe to call from several threads
(without comm).
Ctrl-C stops it (KeyboardInterrupt) within about 0.1 s.)")
      .def(
          "extractor",
          [](py::handle self) {
            Grid& g = grid_of(self);
            auto e = std::make_shared<PyExtractor>();
            {
              py::gil_scoped_release release;
              e->grid = file_errors([&] { return g.whole(); });
            }
            e->extractor = std::make_shared<Extractor>(e->grid);
            return e;
          },
          "extractor() -> Extractor\n\nAn Extractor for browsing iso-values: each call after the first updates the previous surface.")
      .def(
          "coarsen",
          [](py::handle self, double max_error, int cell_floor) {
            Grid& g = grid_of(self);
            py::gil_scoped_release release;
            const auto fine = file_errors([&] { return g.with_tetrahedra(); });  // coarsen reads no index
            return std::make_unique<Grid>(std::make_shared<const PreparedGrid>(cell_floor ? coarsen_floored(*fine, max_error, cell_floor)
                                                                                          : coarsen(*fine, max_error)));
          },
          py::arg("max_error"), py::arg("cell_floor") = 0,
          R"(coarsen(max_error, cell_floor=0) -> Grid

The bisection grid at a coarser error bound (data units), without the volume. cell_floor f > 0: no
tetrahedron finer than cubes of 2**f voxels (except along the volume's far faces), its guaranteed
error measured (stats["error_bound"]) rather than asked for: far fewer triangles on noisy data.)")
      .def(
          "save",
          [](py::handle self, const py::object& path) {
            Grid& g = grid_of(self);
            const std::string p = path_arg(path);
            file_call([&] { save_grid(*g.for_writing(), p); });
          },
          py::arg("path"), "save(path)\n\nWrites the grid (.adg); path: str, bytes or os.PathLike. OSError when it cannot be written.")
      .def_property_readonly(
          "stats",
          [](py::handle self) {
            const Grid& g = grid_of(self);
            py::object stats = json_object(to_json(g.loaded()->stats));
            if (g.bricks) stats["bricks"] = *g.bricks;
            return stats;
          },
          "How the grid was made: the prepare statistics as a dict (the command line's --json; \"bricks\" when prepared in "
          "bricks or over ranks)")
      .def_property_readonly(
          "vertex_count", [](py::handle self) { return grid_of(self).loaded()->grid.vertex_count(); }, "Vertices of the grid")
      .def_property_readonly(
          "tetrahedron_count", [](py::handle self) { return adaptiso::tetrahedron_count(*grid_of(self).loaded()); },
          "Tetrahedra of the grid")
      .def_property_readonly(
          "value_range",
          [](py::handle self) {
            const auto g = grid_of(self).loaded();
            return std::pair{g->grid.source.min, g->grid.source.max};
          },
          "(min, max) of the volume it was prepared from")
      .def_property_readonly(
          "error_bound",
          [](py::handle self) -> py::object {
            const double e = grid_of(self).loaded()->stats.error_bound;
            if (e < 0) return py::none();
            return py::float_(e);
          },
          "The guaranteed max-norm error of a bisection grid (data units); None for a Delaunay grid")
      .def("__repr__", [](py::handle self) {
        const Grid& g = grid_of(self);
        const auto p = g.loaded();
        return "<adaptiso.Grid " + p->stats.grid + ": " + std::to_string(p->grid.vertex_count()) + " vertices, " +
               std::to_string(adaptiso::tetrahedron_count(*p)) + " tetrahedra>";
      });

  py::class_<PyExtractor, std::shared_ptr<PyExtractor>>(
      m, "Extractor",
      "Incremental extraction over one grid (Grid.extractor()). Calls from several threads take turns (one extraction at a time).")
      .def(
          "extract",
          [](py::handle self, double iso) {
            PyExtractor& e = extractor_of(self);
            Mesh copy;
            ExtractStats st;
            {
              py::gil_scoped_release release;
              std::lock_guard lock(e.mutex);
              // Interrupted, the next extract marches afresh (extractor.hpp).
              interruptible([&](const std::atomic<bool>* cancel) { st = e.last = e.extractor->extract(iso, cancel); });
              copy = e.extractor->mesh();
            }
            return make_mesh(std::move(copy), extract_stats(st));
          },
          py::arg("iso"),
          "extract(iso) -> Mesh\n\nThe surface at iso (unpacks as vertices, faces, normals); small steps update the previous one. "
          "Ctrl-C stops it (KeyboardInterrupt) within a stage; the next call then marches afresh.")
      .def_property_readonly(
          "last_stats",
          [](py::handle self) {
            PyExtractor& e = extractor_of(self);
            ExtractStats st;
            {
              py::gil_scoped_release release;
              std::lock_guard lock(e.mutex);
              st = e.last;
            }
            return extract_stats(st);
          },
          "The statistics of the last extract() (the command line's --json figures)");

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
    o.reduce = reduce_options(method, threshold, structural_gradient, sigma, kernel, relative);
    o.tree_depth = tree_depth;
    o.verify = verify;
    o.parallel_delaunay = parallel_delaunay;
    return o;
  };
  m.def(
      "prepare",
      [=](py::handle volume, const std::string& grid, std::optional<double> max_error, bool relative, double max_displacement,
          const std::string& gradients, const std::string& method, double threshold, const std::string& structural_gradient, double sigma,
          int kernel, std::uint32_t tree_depth, bool verify, bool parallel_delaunay, std::optional<std::int64_t> brick_side,
          const py::object& comm) -> py::object {
        const auto setup = [&] {
          return prepare_input(volume, prepare_options(grid, max_error, relative, max_displacement, gradients, method, threshold,
                                                       structural_gradient, sigma, kernel, tree_depth, verify, parallel_delaunay));
        };
        python::CommShare share(comm, brick_side);
        // Without the index: extract(iso) scans, extract(distance=…) and extract(max_error=…) walk
        // the hierarchy, save leaves it out; extractor() builds it (Grid::whole).
        auto p = share.run<std::shared_ptr<PreparedGrid>>(
            setup, [](const Volume& v, const PrepareOptions& o) { return std::make_shared<PreparedGrid>(prepare_without_index(v, o)); });
        if (!p) return py::none();  // a rank other than 0
        auto g = std::make_unique<Grid>(std::move(*p), Grid::Unindexed{});
        if (share.stats()) g->bricks = share.stats()->to_dict();
        return py::cast(std::move(g));
      },
      py::arg("volume"), py::kw_only(), py::arg("grid") = "bisection", py::arg("max_error") = py::none(), py::arg("relative") = false,
      py::arg("max_displacement") = 0.0, py::arg("gradients") = "auto", py::arg("method") = "reconstruction", py::arg("threshold") = 0.0,
      py::arg("structural_gradient") = "central", py::arg("sigma") = 1.0, py::arg("kernel") = 0, py::arg("tree_depth") = kDefaultTreeDepth,
      py::arg("verify") = false, py::arg("parallel_delaunay") = true, py::arg("brick_side") = py::none(), py::arg("comm") = py::none(),
      R"(prepare(volume, *, grid="bisection", max_error=None, relative=False, ...) -> Grid

Prepares a grid for extraction (the command line's `prepare`; the same option names).
volume: a Volume, or a volume file's path, read as adaptiso.read reads it (OSError when it cannot be).
grid: "bisection" (error guaranteed; default) or "delaunay" (the paper's). max_error: max-norm bound,
data units or a fraction of the value range with relative=True; None: DEFAULT_RELATIVE_ERROR of
the range. max_displacement (bisection): voxels an iso-surface may move, to first order.
gradients: "auto", "lsq" or "central". method, threshold, structural_gradient, sigma, kernel: the
Delaunay grid's reduction. verify: measure the error voxel by voxel. ValueError on a bad option.
The extraction index is left until extractor() needs it (extract and save read none; stats holds
its figures): the CT bunny prepares in 5.0-5.3 s peaking at 1.78 GB, against 7.8-8.8 s and 2.52 GB
with it.

brick_side (bisection): compute the error hierarchy in bricks of this many voxels a side (a power
of two >= 2; the same grid, byte for byte). comm: an mpi4py communicator (e.g. MPI.COMM_WORLD under
`mpirun -np N python3 -m mpi4py script.py`): every process calls prepare with its own Volume of the
same dimensions (a memmap is read only in that process's bricks) or the same file's path (rank 0
reads it whole, the others only their bricks where its format allows, as `mpirun adaptiso prepare`
does); the bricks (rank 0's side, by default the largest up to 256 leaving 4 a process) are shared out over the processes, rank 0 returns
the Grid (byte for byte the one a single process makes) and the others None; Grid.stats["bricks"]
tells ranks, bricks per rank, bytes handed to rank 0 and each rank's peak memory. An error on any
process raises on every process, the others' as ValueError "comm: rank R: ...".)");

  m.def(
      "prepare_file",
      [=](py::handle volume, const py::object& path, const std::string& grid, std::optional<double> max_error, bool relative,
          double max_displacement, const std::string& gradients, const std::string& method, double threshold,
          const std::string& structural_gradient, double sigma, int kernel, std::uint32_t tree_depth, bool verify, bool parallel_delaunay,
          std::optional<std::int64_t> brick_side, const py::object& comm) -> py::object {
        std::string p;
        const auto setup = [&] {
          p = path_arg(path);
          return prepare_input(volume, prepare_options(grid, max_error, relative, max_displacement, gradients, method, threshold,
                                                       structural_gradient, sigma, kernel, tree_depth, verify, parallel_delaunay));
        };
        python::CommShare share(comm, brick_side);
        const std::optional<PrepareStats> stats = share.run<PrepareStats>(
            setup, [&](const Volume& v, const PrepareOptions& o) { return file_errors([&] { return prepare_to_file(v, o, p); }); });
        if (!stats) return py::none();  // a rank other than 0
        py::object out = json_object(to_json(*stats));
        if (share.stats()) out["bricks"] = share.stats()->to_dict();
        return out;
      },
      py::arg("volume"), py::arg("path"), py::kw_only(), py::arg("grid") = "bisection", py::arg("max_error") = py::none(),
      py::arg("relative") = false, py::arg("max_displacement") = 0.0, py::arg("gradients") = "auto", py::arg("method") = "reconstruction",
      py::arg("threshold") = 0.0, py::arg("structural_gradient") = "central", py::arg("sigma") = 1.0, py::arg("kernel") = 0,
      py::arg("tree_depth") = kDefaultTreeDepth, py::arg("verify") = false, py::arg("parallel_delaunay") = true,
      py::arg("brick_side") = py::none(), py::arg("comm") = py::none(),
      R"(prepare_file(volume, path, *, grid="bisection", max_error=None, ...) -> dict

prepare(volume, ...) and Grid.save(path) in one (the command line's `prepare`): the same file,
without building the extraction index, which the file leaves out (loading builds it). Returns the
statistics (Grid.stats). ValueError on a bad option, OSError when the path cannot be written.
brick_side and comm as for prepare: with comm, rank 0 writes the file and returns the statistics,
the others return None.)");

  m.def(
      "set_memory_limit",
      [](double bytes) {
        if (!(bytes >= 0 && bytes < 18446744073709551616.0)) throw py::value_error("set_memory_limit: bytes must be 0 or more");
        set_memory_limit(static_cast<std::uint64_t>(bytes));
      },
      py::arg("bytes"),
      "set_memory_limit(bytes)\n\nThe most memory this process may hold, in bytes (0: none but the machine's). Every stage "
      "estimates what it will allocate before it starts; work that does not fit beside what the process holds raises "
      "ValueError with the estimate, instead of ending in a MemoryError or the out-of-memory killer. Without a call, the "
      "environment's ADAPTISO_MEMORY_LIMIT.");
  m.def("memory_limit", &memory_limit,
        "memory_limit() -> int\n\nThe limit in bytes: set_memory_limit's, else ADAPTISO_MEMORY_LIMIT's (0: none).");

  m.def(
      "load",
      [](const py::object& path, bool lazy, const py::object& comm) {
        const std::string p = path_arg(path);
        const auto share = python::comm_transport(comm);
        if (!lazy)
          return file_call([&] {
            return std::make_unique<Grid>(
                std::make_shared<const PreparedGrid>(share ? load_grid_shared(p, GridParts::all, *share) : load_grid(p)));
          });
        return file_call([&] { return load_in_part(p, share.get()); });
      },
      py::arg("path"), py::arg("lazy") = true, py::arg("comm") = py::none(),
      R"(load(path, lazy=True, comm=None) -> Grid

Reads a grid file (.adg); path: str, bytes or os.PathLike. OSError when it cannot be read.
lazy: of a bisection grid, only what extract(distance=...) and extract(max_error=...) read is
loaded now (the CT bunny's 1.8 GB grid: 2.5 s and 0.54 GB instead of 6.5-7 s and 2.1 GB); the
tetrahedra when extract(iso), extractor(), coarsen or save first need them, from the file as it
was (kept open until then). lazy=False reads all of it now: one read instead of two when the grid
will be used at its prepared error (the bunny: load and extract(iso) 7.7-8.3 s, lazily 9.2-10.3 s).
comm: an mpi4py communicator (e.g. MPI.COMM_WORLD under `mpiexec -n N python -m mpi4py ...`)
whose every process loads the same file at once: each gets the grid one process loads, and the
checks, most of a load, are shared out (the bunny over 2 processes: 2.0 s of checks each instead of
4.2). Collective. A file that differs between the processes, or other lazy= on one, or a process
that cannot open its file or read it as a grid file, raises the same OSError on every process
(naming that process). One whose memory limit refuses the load raises alone and leaves the others
waiting (python -m mpi4py then stops the job). A lazy load's tetrahedra, read later, are read by
each process alone, checked in full.)");

  m.def(
      "write_mesh",
      [](const py::object& path, const py::object& vertices, const py::object& faces, const py::object& normals) {
        const std::string p = path_arg(path);
        // A wrong extension is a bad argument (ValueError), not a file that cannot be written.
        if (!is_mesh_file_name(p))
          throw py::value_error(p + ": unknown mesh type '" + std::filesystem::path(p).extension().string() +
                                "' (use .ply, .obj, .stl or .glb)");
        const Mesh mesh = mesh_from_numpy(vertices, faces, normals);
        file_call([&] { write_mesh(mesh, p); });
      },
      py::arg("path"), py::arg("vertices"), py::arg("faces"), py::arg("normals") = py::none(),
      "write_mesh(path, vertices, faces, normals=None)\n\nWrites a mesh by its extension: .ply, .obj, .stl or .glb, in the "
      "coordinates given. ValueError for another extension, OSError when it cannot be written.");

  // The engine of adaptiso.simplify (python/adaptiso/__init__.py wraps it into a Mesh).
  m.def(
      "_simplify",
      [](const py::object& vertices, const py::object& faces, const py::object& normals, double distance, bool checked) {
        const Mesh mesh = mesh_from_numpy(vertices, faces, normals);
        if (!(distance >= 0) || !std::isfinite(distance)) throw py::value_error("distance: must be a finite number >= 0");
        SimplifyStats st;
        Mesh out;
        {
          py::gil_scoped_release release;
          SimplifyOptions how;
          how.checked = checked;
          out = simplify_mesh(mesh, distance, &st, how);
        }
        py::dict stats;
        stats["triangles_before"] = st.triangles_before, stats["triangles_after"] = st.triangles_after;
        stats["distance"] = distance, stats["checked"] = checked, stats["seconds"] = st.seconds;
        stats["chunks"] = st.chunks, stats["chunks_retried"] = st.chunks_retried, stats["chunks_kept"] = st.chunks_kept;
        py::object n = out.normals.empty() ? py::none() : py::object(rows_to_numpy(std::move(out.normals)));
        return py::make_tuple(rows_to_numpy(std::move(out.positions)), rows_to_numpy(std::move(out.triangles)), n, stats);
      },
      py::arg("vertices"), py::arg("faces"), py::arg("normals"), py::arg("distance"), py::arg("checked"));

  // The engine of adaptiso.marching_cubes (python/adaptiso/__init__.py checks the arguments as
  // scikit-image does first). array: [a0, a1, a2] (the last axis fastest in memory after the copy
  // a non-contiguous array gets); positions come back in index units times step, columns in the
  // array's axis order (a0, a1, a2) when reverse_axes, else (a2, a1, a0); normals are the gradient
  // in the spaced coordinates (spacing given in the output's column order), towards lower values.
  m.def(
      "_marching_cubes",
      [](const py::array& array, std::optional<double> level, int step, bool classic, const std::optional<py::array>& mask,
         bool reverse_axes, bool swap_winding, const Vec3& spacing, bool allow_degenerate) {
        auto v = volume_from_array(array, {double(step), double(step), double(step)}, {0, 0, 0}, false);
        py::array mask_bytes;
        if (mask) {
          mask_bytes = py::array::ensure(*mask, py::array::c_style);
          if (!mask_bytes || mask_bytes.itemsize() != 1 || mask_bytes.ndim() != 3 || mask_bytes.shape(0) != v->dims[2] ||
              mask_bytes.shape(1) != v->dims[1] || mask_bytes.shape(2) != v->dims[0])
            throw py::value_error("volume and mask must have the same shape.");
        }
        Mesh mesh;
        std::vector<float> values;
        MarchingCubesStats mc;
        double iso = 0, seconds = 0;
        {
          py::gil_scoped_release release;
          const ValueRange r = finite_range(*v);
          iso = level ? *level : 0.5 * (r.min + r.max);
          if (!(iso >= r.min && iso <= r.max)) {
            py::gil_scoped_acquire gil;
            throw py::value_error("Surface level must be within volume data range.");
          }
          const auto t0 = std::chrono::steady_clock::now();
          MarchingCubesOptions o;
          o.strictly_above = true;  // scikit-image: a voxel equal to the level is outside
          o.edge_margin = 0;        // and a vertex may lie on a voxel (degenerate triangles, as theirs)
          o.classic_table = classic;
          o.mask = mask ? static_cast<const std::uint8_t*>(mask_bytes.data()) : nullptr;
          o.values = &values;
          mesh = marching_cubes(*v, iso, o, &mc);
          if (!allow_degenerate) remove_degenerate(mesh, values);
          // The library's frame is (x, y, z) = (a2, a1, a0); reversing the columns is a reflection,
          // which the caller's swap_winding accounts for with the gradient direction.
          for (std::size_t i = 0; i < mesh.positions.size(); ++i) {
            auto& p = mesh.positions[i];
            auto& n = mesh.normals[i];
            if (reverse_axes) std::swap(p[0], p[2]), std::swap(n[0], n[2]);
            // Index-space gradient → spaced: each component divided by its spacing, then unit length.
            double g[3], len = 0;
            for (int a = 0; a < 3; ++a) g[a] = n[a] / spacing[a], len += g[a] * g[a];
            len = std::sqrt(len);
            if (len > 0)
              for (int a = 0; a < 3; ++a) n[a] = static_cast<float>(g[a] / len);
          }
          if (swap_winding)
            for (auto& t : mesh.triangles) std::swap(t[1], t[2]);
          seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        }
        py::dict stats;
        stats["iso"] = iso;
        stats["triangles"] = mesh.triangle_count();
        stats["vertices"] = mesh.vertex_count();
        stats["cubes_cut"] = mc.cubes_cut;
        stats["ambiguous_faces"] = mc.ambiguous_faces;
        stats["seconds"] = seconds;
        return py::make_tuple(rows_to_numpy(std::move(mesh.positions)), rows_to_numpy<std::int32_t>(std::move(mesh.triangles)),
                              rows_to_numpy(std::move(mesh.normals)), vector_to_numpy(std::move(values)), stats);
      },
      py::arg("array"), py::arg("level"), py::arg("step"), py::arg("classic"), py::arg("mask"), py::arg("reverse_axes"),
      py::arg("swap_winding"), py::arg("spacing"), py::arg("allow_degenerate"),
      "Internal: adaptiso.marching_cubes' engine (use adaptiso.marching_cubes).");

  m.def(
      "reduce",
      [](py::handle volume, std::optional<double> max_error, bool relative, const std::string& method, double threshold,
         const std::string& gradient, double sigma, int kernel) {
        const Volume& v = volume_of(volume);
        ReduceOptions o = reduce_options(method, threshold, gradient, sigma, kernel, relative);
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
      R"(reduce(volume, *, max_error=None, relative=False, method="reconstruction", ...) -> numpy.ndarray

The paper's vertex reduction (§2.1) alone: the kept voxels as an int64 array (N, 3) of [z, y, x]
indices (array[tuple(kept.T)] gives their values), in ascending file order.)");
}
