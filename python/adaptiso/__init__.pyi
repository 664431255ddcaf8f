# Type hints for the package adaptiso (its compiled part, adaptiso._core, has none of its own).
import os
from typing import Any, Literal, Optional, Sequence, Tuple, Union, overload

import numpy as np
import numpy.typing as npt

__version__: str
DEFAULT_RELATIVE_ERROR: float

_Path = Union[str, bytes, "os.PathLike[str]", "os.PathLike[bytes]"]
_Vec3 = Tuple[float, float, float]

class Volume:
    """A scalar volume on a regular grid, indexed array[z, y, x]; spacing and origin (x, y, z)."""

    def __init__(self, array: Any, spacing: Optional[Sequence[float]] = ..., origin: Optional[Sequence[float]] = ...) -> None: ...
    @property
    def dims(self) -> Sequence[int]: ...
    @property
    def shape(self) -> Tuple[int, int, int]: ...
    @property
    def spacing(self) -> Sequence[float]: ...
    @property
    def origin(self) -> Sequence[float]: ...
    @property
    def direction(self) -> Tuple[_Vec3, _Vec3, _Vec3]: ...
    @property
    def dtype(self) -> np.dtype: ...
    @property
    def is_view(self) -> bool: ...
    @property
    def array(self) -> npt.NDArray[Any]: ...
    def range(self) -> Tuple[float, float]: ...

class Mesh(tuple):
    """(vertices, faces, normals[, values]) with stats, axes and hand-offs to VTK, meshio, napari."""

    stats: dict
    axes: Literal["xyz", "zyx"]
    def __new__(
        cls,
        vertices: npt.ArrayLike,
        faces: npt.ArrayLike,
        normals: Optional[npt.ArrayLike] = ...,
        values: Optional[npt.ArrayLike] = ...,
        *,
        stats: Optional[dict] = ...,
        axes: Literal["xyz", "zyx"] = ...,
    ) -> "Mesh": ...
    @property
    def vertices(self) -> npt.NDArray[np.floating]: ...
    @property
    def faces(self) -> npt.NDArray[np.integer]: ...
    @property
    def normals(self) -> Optional[npt.NDArray[np.float32]]: ...
    @property
    def values(self) -> Optional[npt.NDArray[np.float32]]: ...
    def to_vtk(self) -> Any: ...
    def to_meshio(self) -> Any: ...
    def save(self, path: _Path) -> None: ...
    def to_napari(self) -> Tuple[npt.NDArray[np.floating], npt.NDArray[np.integer], npt.NDArray[np.floating]]: ...

class Extractor:
    """Incremental extraction over one grid (Grid.extractor()); calls from several threads take turns."""

    def extract(self, iso: float) -> Mesh: ...
    @property
    def last_stats(self) -> dict: ...

class Grid:
    """A prepared tetrahedral grid (prepare or load); its extraction index is built when extractor() first needs it."""

    def extract(self, iso: float, max_error: Optional[float] = ..., relative: bool = ..., distance: Optional[float] = ...,
                collapse: Optional[int] = ...) -> Mesh: ...
    def extractor(self) -> Extractor: ...
    def coarsen(self, max_error: float, cell_floor: int = ...) -> "Grid": ...
    def save(self, path: _Path) -> None: ...
    @property
    def stats(self) -> dict: ...
    @property
    def vertex_count(self) -> int: ...
    @property
    def tetrahedron_count(self) -> int: ...
    @property
    def value_range(self) -> Tuple[float, float]: ...
    @property
    def error_bound(self) -> Optional[float]: ...

def read(path: _Path) -> Volume: ...
def load(path: _Path, lazy: bool = True, comm: Any = None) -> Grid:
    """Reads a grid file (.adg). lazy: of a bisection grid, only what extract(distance=...) and
    extract(max_error=...) read is loaded now; the tetrahedra, from the file as it was (kept open),
    when extract(iso), extractor(), coarsen or save first need them. lazy=False reads all now.
    comm: an mpi4py communicator whose every process loads the same file at once, the checks
    shared out (collective)."""
    ...
def set_memory_limit(bytes: float) -> None: ...
def memory_limit() -> int: ...
@overload
def prepare(
    volume: Union[Volume, _Path],
    *,
    grid: Literal["bisection", "delaunay"] = ...,
    max_error: Optional[float] = ...,
    relative: bool = ...,
    max_displacement: float = ...,
    gradients: Literal["auto", "lsq", "central"] = ...,
    method: Literal["reconstruction", "structural", "both"] = ...,
    threshold: float = ...,
    structural_gradient: Literal["central", "canny"] = ...,
    sigma: float = ...,
    kernel: int = ...,
    tree_depth: int = ...,
    verify: bool = ...,
    parallel_delaunay: bool = ...,
    brick_side: Optional[int] = ...,
    comm: None = ...,
) -> Grid: ...
@overload
def prepare(
    volume: Union[Volume, _Path],
    *,
    grid: Literal["bisection", "delaunay"] = ...,
    max_error: Optional[float] = ...,
    relative: bool = ...,
    max_displacement: float = ...,
    gradients: Literal["auto", "lsq", "central"] = ...,
    method: Literal["reconstruction", "structural", "both"] = ...,
    threshold: float = ...,
    structural_gradient: Literal["central", "canny"] = ...,
    sigma: float = ...,
    kernel: int = ...,
    tree_depth: int = ...,
    verify: bool = ...,
    parallel_delaunay: bool = ...,
    brick_side: Optional[int] = ...,
    comm: Any,
) -> Optional[Grid]: ...
@overload
def prepare_file(
    volume: Union[Volume, _Path],
    path: _Path,
    *,
    grid: Literal["bisection", "delaunay"] = ...,
    max_error: Optional[float] = ...,
    relative: bool = ...,
    max_displacement: float = ...,
    gradients: Literal["auto", "lsq", "central"] = ...,
    method: Literal["reconstruction", "structural", "both"] = ...,
    threshold: float = ...,
    structural_gradient: Literal["central", "canny"] = ...,
    sigma: float = ...,
    kernel: int = ...,
    tree_depth: int = ...,
    verify: bool = ...,
    parallel_delaunay: bool = ...,
    brick_side: Optional[int] = ...,
    comm: None = ...,
) -> dict: ...
@overload
def prepare_file(
    volume: Union[Volume, _Path],
    path: _Path,
    *,
    grid: Literal["bisection", "delaunay"] = ...,
    max_error: Optional[float] = ...,
    relative: bool = ...,
    max_displacement: float = ...,
    gradients: Literal["auto", "lsq", "central"] = ...,
    method: Literal["reconstruction", "structural", "both"] = ...,
    threshold: float = ...,
    structural_gradient: Literal["central", "canny"] = ...,
    sigma: float = ...,
    kernel: int = ...,
    tree_depth: int = ...,
    verify: bool = ...,
    parallel_delaunay: bool = ...,
    brick_side: Optional[int] = ...,
    comm: Any,
) -> Optional[dict]: ...
def simplify(mesh: Any, distance: float, *, checked: bool = ...) -> Mesh: ...
def write_mesh(path: _Path, vertices: npt.ArrayLike, faces: npt.ArrayLike, normals: Optional[npt.ArrayLike] = ...) -> None: ...
def marching_cubes(
    volume: Any,
    level: Optional[float] = ...,
    *,
    spacing: Optional[Sequence[float]] = ...,
    gradient_direction: Literal["descent", "ascent"] = ...,
    step_size: int = ...,
    allow_degenerate: bool = ...,
    method: Literal["lewiner", "lorensen"] = ...,
    mask: Optional[npt.ArrayLike] = ...,
) -> Mesh: ...
def reduce(
    volume: Volume,
    *,
    max_error: Optional[float] = ...,
    relative: bool = ...,
    method: Literal["reconstruction", "structural", "both"] = ...,
    threshold: float = ...,
    gradient: Literal["central", "canny"] = ...,
    sigma: float = ...,
    kernel: int = ...,
) -> npt.NDArray[np.int64]: ...
