"""Volumes from where Python users keep them: image objects with their geometry (nibabel)."""
import numpy as np


def image_geometry(image):
    """An image object's voxels and geometry, as adaptiso.read takes them from the same file.

    Returns None for anything that is not an image object (arrays, buffers, objects with
    __array__), else (data, spacing, origin, direction): data indexed in the file's order [i, j, k]
    (nibabel's; x fastest on disk, so data.T is the [z, y, x] view of a memmap, without a copy),
    spacing (3,) in the same order, origin (3,) and the 3x3 direction matrix row-major as 9 floats
    (column a: the world direction of index axis a).

    NIfTI images take the sform when its code is set, else the qform, else pixdim with the origin
    at 0, as adaptiso.read does; other nibabel images (MGH, Analyze, ...) their affine.
    """
    if isinstance(image, np.ndarray) or not all(hasattr(image, a) for a in ("dataobj", "header", "affine")):
        return None
    data = np.asanyarray(image.dataobj)  # a memmap when the file is uncompressed and unscaled
    while data.ndim > 3 and data.shape[-1] == 1:  # a 3D image stored with trailing axes of size 1
        data = data[..., 0]
    if data.ndim != 3:
        raise ValueError(f"image: the data must have 3 dimensions, got shape {data.shape}")
    header = image.header
    affine = None
    getters = [getattr(header, name, None) for name in ("get_sform", "get_qform")]
    if all(callable(g) for g in getters):
        for get in getters:
            matrix, code = get(coded=True)
            if matrix is not None and code is not None and code > 0:
                affine = np.asarray(matrix, dtype=float)
                break
    else:
        affine = np.asarray(image.affine, dtype=float)
    if affine is None:
        zooms = [float(z) for z in header.get_zooms()[:3]]
        spacing = tuple(abs(z) if np.isfinite(z) and z != 0 else 1.0 for z in zooms)
        return data, spacing, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    columns = affine[:3, :3]
    spacing = np.sqrt((columns**2).sum(axis=0))
    if not np.all(spacing > 0):
        raise ValueError("image: orientation matrix has a zero column")
    direction = columns / spacing
    return data, tuple(float(s) for s in spacing), tuple(float(o) for o in affine[:3, 3]), tuple(float(d) for d in direction.ravel())
