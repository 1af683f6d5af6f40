"""Grouping of fragments into objects by the convexity of their images.

The watershed cuts a retina into intensity-homogeneous fragments; an object is usually
several (the faces of a box, the cells of a checker texture). Touching fragments are
joined, longest shared boundary first, unless their union holds a **concave notch of
ground** where their outlines meet (``segmentation.ground_notches``). Every shape of a
world is convex, so its image is convex: two fragments of one object never enclose ground
between them deeper than ``notch_px`` (digitisation leaves about a pixel). Where one
object stands in front of another, the outlines meet at T-junctions with ground in the
corner: every object stands on the ground, so the one in front reaches lower in the
image than the bottom of the one behind it.

This replaces joining fragments whose 3-D centres lie within a fixed ground distance
(0.22 m), which joined objects standing close behind one another and split large ones.
A test for a depth step along the shared boundary (occlusion seen by stereo) was built
and measured; docs/perception.md says why it is not used.

Fragments smaller than the smallest ROI (the rim slivers the watershed leaves) are first
given to the neighbour they share the longest boundary with (``absorb_slivers``).
"""

from __future__ import annotations

from collections.abc import Mapping

import cv2
import numpy as np

from roger_perception.segmentation import (
    DEFECT_MARGIN,
    deepest_defect,
    ground_notches,
    label_boxes,
)


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
    n1 = int(labels.max()) + 1
    keys = []
    for a, b in ((labels[:, 1:], labels[:, :-1]), (labels[1:], labels[:-1])):
        sel = (a != b) & (a > 0) & (b > 0)
        lo = np.minimum(a[sel], b[sel]).astype(np.int64)
        keys.append(lo * n1 + np.maximum(a[sel], b[sel]))
    pairs, counts = np.unique(np.concatenate(keys), return_counts=True)
    return {(int(k // n1), int(k % n1)): int(c)
            for k, c in zip(pairs.tolist(), counts.tolist(), strict=True)}


def owner_lut(owner: Mapping[int, int], n: int) -> np.ndarray:
    """Lookup table from fragment label (0..n) to its object's representative label (0 for
    the ground): ``owner_lut(owner, n)[frag]`` is the object label image."""
    lut = np.zeros(n + 1, np.int32)
    for i, g in owner.items():
        lut[i] = g
    return lut


def absorb_slivers(frag: np.ndarray, min_pixels: int) -> np.ndarray:
    """Give every fragment smaller than ``min_pixels`` to the neighbour it shares the
    longest boundary with (repeated, so that a chain of slivers reaches a large fragment).

    The watershed leaves slivers along the outlines (foreground the ground's flood
    reached) and between markers; none is an object by itself. Slivers that touch only
    other slivers form one fragment.

    Returns:
        The new labels (those of the large fragments are kept).
    """
    area = np.bincount(frag.ravel())
    small = {int(i) for i in np.nonzero((area > 0) & (area < min_pixels))[0] if i > 0}
    if not small:
        return frag
    neighbours: dict[int, list[tuple[int, int]]] = {i: [] for i in small}
    for (p, q), length in adjacency(frag).items():
        if p in small:
            neighbours[p].append((length, q))
        if q in small:
            neighbours[q].append((length, p))
    target = {i: i for i in range(area.size)}

    def root(i: int) -> int:
        while target[i] != i:
            i = target[i]
        return i

    changed = True
    while small and changed:
        changed = False
        for i in sorted(small):
            large = [(length, -o) for length, o in neighbours[i] if o not in small]
            if large:
                target[i] = root(-max(large)[1])
                small.discard(i)
                changed = True
    for i in small:
        for _, o in neighbours[i]:
            if o in small and root(o) != root(i):
                target[root(i)] = root(o)
    lut = np.array([root(i) for i in range(area.size)], np.int32)
    return lut[frag]


def group_fragments(frag: np.ndarray, ground: np.ndarray,
                    touching: Mapping[tuple[int, int], int], min_pixels: int,
                    notch_px: float) -> dict[int, int]:
    """Join fragments into objects (module docstring).

    First every touching pair whose own union holds a ground notch deeper than
    ``notch_px`` where their outlines meet is kept apart. Then pairs are taken longest
    shared boundary first; two groups join unless they hold such a pair, or their union
    holds such a notch where the two groups' outlines meet (a notch that one group holds
    alone, e.g. where a third object was cut off it, says nothing about these two). A
    refusal is kept: a notch only deepens as a group grows.

    Args:
        frag: Fragment labels (0 ground).
        ground: Where the retina shows ground beyond doubt (``segmentation.sure_ground``).
        touching: Shared boundary lengths of touching fragment pairs (``adjacency``).
        min_pixels: Fragments with fewer pixels are left alone (``absorb_slivers`` first).
        notch_px: Deepest ground notch a union may hold.

    Returns:
        The object (a representative fragment label) of every fragment present.
    """
    area = np.bincount(frag.ravel())
    labels = [int(i) for i in np.nonzero(area)[0] if i > 0]
    parent = {i: i for i in labels}
    apart: dict[int, set[int]] = {i: set() for i in labels}
    boxes = label_boxes(frag)
    members = {i: [i] for i in labels}

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def masks(a: int, b: int) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
        (ay0, ax0, ay1, ax1), (by0, bx0, by1, bx1) = boxes[a], boxes[b]
        y0, x0, y1, x1 = min(ay0, by0), min(ax0, bx0), max(ay1, by1), max(ax1, bx1)
        crop = frag[y0:y1, x0:x1]
        in_a, in_b = np.zeros(area.size, bool), np.zeros(area.size, bool)
        in_a[members[a]], in_b[members[b]] = True, True
        return in_a[crop], in_b[crop], (y0, x0)

    def notched(a: int, b: int) -> bool:
        in_a, in_b, (y0, x0) = masks(a, b)
        h, w = in_a.shape
        union = in_a | in_b
        return deepest_defect(union) >= notch_px - DEFECT_MARGIN and bool(ground_notches(
            union, ground[y0:y0 + h, x0:x0 + w], (in_a, in_b), deeper_than=notch_px))

    pairs = sorted(((pq, n) for pq, n in touching.items()
                    if area[pq[0]] >= min_pixels and area[pq[1]] >= min_pixels),
                   key=lambda kv: (-kv[1], kv[0]))
    # Two fragments whose own union holds a notch are never one object, whatever joins
    # them first.
    for (p, q), _ in pairs:
        if notched(p, q):
            _keep_apart(apart, p, q)
    for (p, q), _ in pairs:
        a, b = find(p), find(q)
        if a == b or b in apart[a]:
            continue
        if (len(members[a]) > 1 or len(members[b]) > 1) and notched(a, b):
            _keep_apart(apart, a, b)
            continue
        (ay0, ax0, ay1, ax1), (by0, bx0, by1, bx1) = boxes[a], boxes[b]
        parent[a] = b
        boxes[b] = (min(ay0, by0), min(ax0, bx0), max(ay1, by1), max(ax1, bx1))
        members[b] += members.pop(a)
        apart[b] |= apart[a]
        for other in apart[a]:
            apart[other].add(b)
    return {i: find(i) for i in labels}


def _keep_apart(apart: dict[int, set[int]], a: int, b: int) -> None:
    apart[a].add(b)
    apart[b].add(a)
