"""Clean-up of a finished mesh: vertices of a face that landed on one point are merged.

>>> import numpy as np
>>> v = np.array([[0.0, 0, 0], [1, 0, 0], [1, 0, 0], [0, 1, 0]])  # vertices 1 and 2 coincide
>>> _collapse_coincident(v, np.array([[0, 1, 2], [0, 2, 3]]), np.zeros((4, 3)))[1]  # would open a border: kept
array([[0, 1, 2],
       [0, 2, 3]])
"""

from __future__ import annotations

import numpy as np


def _edge_counts(faces: np.ndarray) -> np.ndarray:
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(edges[:, 0] * (int(faces.max()) + 1) + edges[:, 1], return_counts=True)[1]


def _collapse_coincident(
    verts: np.ndarray, faces: np.ndarray, gradient: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge the vertices of a face that landed on the same point; drop the faces that collapse.

    Newton steps (the fallback of the projection) can move two vertices of a triangle next to
    a sharp crease onto the same point: a zero-area triangle, which STL readers drop (VTK's
    merges points, leaving a hole).  Collapsing such an edge removes the two triangles that
    share it and keeps the mesh closed, unless the collapse would pinch it (an edge then in
    more than two faces, or a changed border): then the mesh is returned unchanged.
    """
    if len(faces) == 0:
        return verts, faces, gradient
    # coincident vertices have equal keys (a hash of the coordinates' bits, -0.0 as 0.0): only the
    # faces with two equal keys (few or none) are compared coordinate by coordinate
    bits = (verts + 0.0).view(np.int64)
    key = bits[:, 0] * _HASH[0] ^ bits[:, 1] * _HASH[1] ^ bits[:, 2]  # wraps around: a hash
    k = [key[faces[:, i]] for i in range(3)]
    suspect = faces[(k[0] == k[1]) | (k[1] == k[2]) | (k[2] == k[0])]
    corners = [verts[suspect[:, i]] for i in range(3)]
    pairs = [suspect[(corners[i] == corners[j]).all(axis=1)][:, [i, j]] for i, j in ((0, 1), (1, 2), (2, 0))]
    pairs = np.concatenate(pairs)
    if len(pairs) == 0:
        return verts, faces, gradient
    label = np.arange(len(verts))
    while True:  # every vertex of a coincident cluster points to the cluster's smallest index
        low = np.minimum(label[pairs[:, 0]], label[pairs[:, 1]])
        new = label.copy()
        np.minimum.at(new, pairs[:, 0], low)
        np.minimum.at(new, pairs[:, 1], low)
        new = new[new]
        if np.array_equal(new, label):
            break
        label = new
    merged = label[faces]
    keep = (merged[:, 0] != merged[:, 1]) & (merged[:, 1] != merged[:, 2]) & (merged[:, 2] != merged[:, 0])
    merged = merged[keep]
    before, after = _edge_counts(faces), _edge_counts(merged)
    if after.max() > 2 or (after == 1).sum() != (before == 1).sum():
        return verts, faces, gradient  # a collapse would pinch the surface: keep the zero-area triangles
    used = np.unique(merged)
    index = np.full(len(verts), -1, dtype=np.int64)
    index[used] = np.arange(len(used))
    return verts[used], index[merged], gradient[used]


_HASH = (6364136223846793005, 1442695040888963407)  # odd 64-bit multipliers (Knuth's MMIX LCG)
