"""Grouping of fragments into objects by their stereo depth.

The watershed cuts a retina into intensity-homogeneous fragments; an object is usually
several (the faces of a box, the cells of a checker texture), and two objects that touch
in the image are never one. Two fragments that share a boundary belong to the same
object when their 3-D centres (left-retina centroid at the fragment's plane-sweep depth)
lie within ``merge_distance_m`` of each other on the ground plane: faces of one object
are closer than that, objects standing behind one another are farther. A fragment whose
depth is unreliable (too few usable pixels, or a flat cost curve: its only edges run
along the epipolar lines) has no vote: it joins the neighbour it shares the longest
boundary with.
"""

from __future__ import annotations

from collections.abc import Mapping

import cv2
import numpy as np


def near_other_label(labels: np.ndarray, band_px: int) -> np.ndarray:
    """Pixels of a label within ``band_px`` pixels (square) of a different non-zero label.

    Their right-retina match is disturbed where one object occludes another (the band
    moves with the nearer object), so they are left out of depth estimates.
    """
    if band_px <= 0:
        return np.zeros(labels.shape, bool)
    kernel = np.ones((2 * band_px + 1, 2 * band_px + 1), np.uint8)
    lf = labels.astype(np.float32)
    high = cv2.dilate(lf, kernel)
    low = cv2.erode(np.where(labels > 0, lf, np.float32(3e38)), kernel)
    return (labels > 0) & ((high != lf) | (low != lf))


def adjacency(labels: np.ndarray) -> dict[tuple[int, int], int]:
    """Shared boundary length (4-neighbour pixel pairs) of every pair of touching labels."""
    out: dict[tuple[int, int], int] = {}
    for a, b in ((labels[:, 1:], labels[:, :-1]), (labels[1:], labels[:-1])):
        sel = (a != b) & (a > 0) & (b > 0)
        if not sel.any():
            continue
        lo, hi = np.minimum(a[sel], b[sel]), np.maximum(a[sel], b[sel])
        pairs, counts = np.unique(np.stack([lo, hi], 1), axis=0, return_counts=True)
        for (p, q), c in zip(pairs.tolist(), counts.tolist(), strict=True):
            out[(p, q)] = out.get((p, q), 0) + c
    return out


def group_fragments(touching: Mapping[tuple[int, int], int], labels: list[int],
                    reliable: Mapping[int, bool], ground_xy: Mapping[int, np.ndarray],
                    merge_distance_m: float) -> dict[int, int]:
    """Join fragments into objects.

    Args:
        touching: Shared boundary lengths of touching fragment pairs (``adjacency``).
        labels: All fragment labels.
        reliable: Whether each fragment's depth can be trusted.
        ground_xy: Robot-frame (x, y) of each fragment's 3-D centre.
        merge_distance_m: Largest ground distance of the centres of two touching,
            reliable fragments of one object.

    Returns:
        The object (a representative fragment label) of every fragment.
    """
    parent = {i: i for i in labels}

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for (p, q), _ in sorted(touching.items(), key=lambda kv: -kv[1]):
        if reliable[p] and reliable[q] and float(
                np.hypot(*(ground_xy[p] - ground_xy[q]))) <= merge_distance_m:
            parent[find(p)] = find(q)
    # Unreliable fragments join the group they share the longest boundary with; repeat so
    # that a chain of unreliable fragments reaches a reliable one.
    floating = {i for i in labels if not reliable[i]}
    changed = True
    while floating and changed:
        changed = False
        for i in sorted(floating):
            best, best_len = None, 0
            for (p, q), length in touching.items():
                other = q if p == i else p if q == i else None
                if other is None or other in floating or length <= best_len:
                    continue
                best, best_len = other, length
            if best is not None:
                parent[find(i)] = find(best)
                floating.discard(i)
                changed = True
    # What is left touches only other unreliable fragments: those form one object.
    for (p, q) in touching:
        if p in floating and q in floating:
            parent[find(p)] = find(q)
    return {i: find(i) for i in labels}
