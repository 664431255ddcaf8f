"""scikit-image's marching_cubes signature and behaviour over the library's marching cubes."""
import numpy as np

from . import _core
from ._inputs import image_geometry
from ._mesh import Mesh

# The dtypes the library reads in place; others are converted as scikit-image converts them all
# (it works in float32), here to float32, or float64 where float32 would round integers.
_NATIVE = {np.dtype(t) for t in (np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32, np.float32, np.float64)}


def marching_cubes(volume, level=None, *, spacing=None, gradient_direction="descent", step_size=1, allow_degenerate=True,
                   method="lewiner", mask=None):
    """Full-resolution marching cubes with scikit-image's arguments, results and exceptions
    (``skimage.measure.marching_cubes``), several times faster, without copying the volume.

    Parameters
    ----------
    volume : (M, N, P) array-like or image object
        A numpy array (C- or Fortran-contiguous ones and memmaps are read in place; other
        layouts are copied once), anything with the buffer protocol or ``__array__``, or a
        nibabel image (its data in the file's index order, spacing from its affine/zooms).
        NaN and Inf are refused (ValueError).
    level : float, optional
        Contour value; default the middle of the value range. A voxel equal to the level is
        outside the surface (as scikit-image), so the maximum gives no surface.
    spacing : length-3 sequence of floats, optional
        Voxel spacing in the array's index order; default (1, 1, 1), or an image's voxel size.
    gradient_direction : {'descent', 'ascent'}
        The winding of the faces, as scikit-image's: 'descent' winds them counter-clockwise seen
        from the higher values, 'ascent' from the lower. The normals point towards lower values
        in both cases (as theirs).
    step_size : int
        March every step_size-th voxel along each axis (cubes of step_size voxels).
    allow_degenerate : bool
        False removes zero-area triangles and merges the vertices they join.
    method : {'lewiner', 'lorensen'}
        'lorensen': Lorensen & Cline's classic case table, as scikit-image's 'lorensen' (the same
        triangles). 'lewiner' (default): this library's crack-free table, whose contours are the
        classic table's and whose pieces of 4 to 7 cut edges are fanned from one edge. Lewiner's
        own tables (ambiguities decided by the trilinear interior, extra vertices inside some
        cubes) are not implemented: both methods here give the classic table's vertices and
        triangle count.
    mask : (M, N, P) array of bool, optional
        Only cubes whose far corner (the one with the largest indices) is True are marched, as
        scikit-image does.

    Returns
    -------
    Mesh
        Unpacks as ``verts, faces, normals, values``: verts (V, 3) in the array's index order
        times spacing (float32; float64 when spacing is not (1, 1, 1), as scikit-image's), faces
        (F, 3) int32 (int64 with allow_degenerate=False), unit normals (V, 3) float32 (the
        gradient in the spaced coordinates; scikit-image's ignore spacing), values (V,) float32:
        per vertex the largest value range (max - min) of the cubes around it. ``.stats`` holds
        the triangle, vertex and cut-cube counts and the seconds the marching took.

    Raises
    ------
    ValueError
        Not a 3D volume, smaller than 2 along an axis, a level outside the value range, a
        spacing not of length 3 (or not positive), step_size < 1, a mask of another shape, an
        unknown gradient_direction or method (including scikit-image's removed '_lorensen').
    RuntimeError
        No surface at that level (as scikit-image).
    """
    if method not in ("lewiner", "lorensen"):
        if method == "_lorensen":
            raise ValueError("method: '_lorensen' (scikit-image's private old implementation, gone from its later releases) is not provided; use 'lorensen'")
        raise ValueError("method should be either 'lewiner' or 'lorensen'")
    image = image_geometry(volume)
    axes = "zyx"
    image_spacing = None
    if image is not None:
        array, image_spacing, axes = image[0], image[1], "xyz"  # the file's order [i, j, k] is x, y, z
    else:
        try:
            array = volume if isinstance(volume, np.ndarray) else np.asarray(volume)
        except Exception as e:  # noqa: BLE001 - what numpy says goes with it
            raise ValueError("Input volume should be a 3D numpy array.") from e
    if array.ndim != 3 or array.dtype.kind not in "biuf":
        raise ValueError("Input volume should be a 3D numpy array.")
    if min(array.shape) < 2:
        raise ValueError("Input array must be at least 2x2x2.")
    if array.dtype not in _NATIVE:
        wide = array.dtype.kind in "iu" and array.dtype.itemsize > 2
        array = array.astype(np.float64 if wide else np.float32)
    if level is not None:
        level = float(level)
        if np.isnan(level):
            raise ValueError("Surface level must be within volume data range.")
    if spacing is None:
        spacing = image_spacing if image_spacing is not None else (1.0, 1.0, 1.0)
    if len(spacing) != 3:
        raise ValueError("`spacing` must consist of three floats.")
    spacing = tuple(float(s) for s in spacing)
    if not all(np.isfinite(s) and s > 0 for s in spacing):
        raise ValueError(f"`spacing` must consist of three positive finite floats, got {spacing}")
    step_size = int(step_size)
    if step_size < 1:
        raise ValueError("step_size must be at least one.")
    if gradient_direction not in ("descent", "ascent"):
        raise ValueError(f"Incorrect input {gradient_direction} in `gradient_direction`, see docstring.")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != array.shape:
            raise ValueError("volume and mask must have the same shape.")

    # The library marches an array whose last axis is fastest in memory. A Fortran-ordered array
    # (nibabel's memmaps) is marched through its transpose, a view; its columns then come back
    # in the array's own order, without the reflection a C-ordered array's (z, y, x) needs.
    reverse_axes = True
    if array.flags.f_contiguous and not array.flags.c_contiguous:
        array, reverse_axes = array.T, False
        mask = None if mask is None else mask.T
    if step_size > 1:  # a strided view: the library copies it, 1/step_size³ of the volume
        array = array[::step_size, ::step_size, ::step_size]
        mask = None if mask is None else mask[::step_size, ::step_size, ::step_size]
    if mask is not None:
        mask = np.ascontiguousarray(mask, dtype=bool)
    # The library winds faces counter-clockwise seen from lower values; scikit-image's 'descent'
    # from higher ones. A reflection (reverse_axes) turns the winding once more.
    swap_winding = (gradient_direction == "descent") != reverse_axes
    verts, faces, normals, values, stats = _core._marching_cubes(array, level, step_size, method == "lorensen", mask, reverse_axes,
                                                                 swap_winding, spacing, allow_degenerate)
    if not len(verts):
        raise RuntimeError("No surface found at the given iso value.")
    if spacing != (1.0, 1.0, 1.0):  # float32 times float64: scikit-image's float64 vertices
        verts = verts * np.array(spacing)
    if not allow_degenerate:  # scikit-image's remove_degenerate_faces gives these dtypes
        verts = verts.astype(np.float32, copy=False)
        faces = faces.astype(np.int64)
    return Mesh(verts, faces, normals, values, stats=stats, axes=axes)
