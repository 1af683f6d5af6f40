"""Random worlds that pass every world-file rule: for tests on unseen worlds and experiments.

Objects are drawn as categories (shape, size, intensity, weight, texture), each placed a
few times, at random positions in reach and view, without overlap; optionally a few more
in view beyond the arms' reach. Seeded: the same arguments give the same world (and the
objects in reach do not depend on ``out_of_reach``). Two recipes narrow the draw:
``shape_twins`` (categories that differ only in shape) and ``yaw_copies`` (each
category's copies turned over a quarter turn).
"""

from __future__ import annotations

import math

import numpy as np

from roger_common.errors import WorldFileError
from roger_common.types import ObjectSpec, WorldSpec
from roger_sim.world import (
    SHAPES,
    footprint_radius,
    in_reach,
    object_from_dict,
    parse_world,
    world_to_dict,
)


def random_world(n_categories: int, copies: int, seed: int, size_range: tuple[float, float] =
                 (0.10, 0.18), textures: tuple[str, ...] = ("plain",), name: str = "",
                 min_gap: float = 0.04, max_tries: int = 20000,
                 out_of_reach: int = 0, *, shape_twins: bool = False,
                 yaw_copies: bool = False, restarts: int = 8) -> WorldSpec:
    """A world of ``n_categories`` categories, each placed ``copies`` times in reach.

    Grey levels are drawn from 50-130, the range of the paper's Table 1 (59-99) widened a
    little: brighter surfaces saturate the intensity features (docs/perception.md).

    Args:
        n_categories: Distinct categories (shape, size, intensity, weight, texture).
        copies: Objects per category.
        seed: Seed of every random draw.
        size_range: Object sizes in metres.
        textures: Textures the categories may use.
        name: World name (default ``random_<n>x<copies>_<seed>``).
        min_gap: Free space kept between two objects' footprints (metres), so that they do
            not touch in the retinas.
        max_tries: Placement attempts (of one object each) before the placement starts
            over.
        out_of_reach: Objects placed after those, in view but beyond the arms' reach
            (1.25-1.7 m away, bearing within 50 degrees), one of each category in turn,
            named ``c<category>_far<k>``.
        shape_twins: Categories that differ only in shape: one size, grey level, weight
            and texture, drawn once from the usual ranges, shared by every category, and a
            distinct shape each (so at most ``len(SHAPES)`` categories). The rule that keeps
            categories apart in grey level is off: here they share it on purpose. Adds
            ``_twins`` to the default name.
        yaw_copies: Copy ``k`` of each category stands at yaw ``k * (pi / 2) / (copies -
            1)`` (rounded to 0.01 rad; a single copy at 0) instead of a random yaw, so the
            copies show one category from views spread over a quarter turn. The random
            yaw is still drawn and thrown away, so positions are those of the same call
            without the flag. Objects beyond reach keep a random yaw. Adds ``_yaw`` to the
            default name (after ``_twins``).
        restarts: Times the placement starts over (every object again, the categories
            kept, the rng drawing on) when ``max_tries`` attempts did not place them all:
            one by one, the first objects can leave no room for the last (seed 10075 of
            the inspection recipe). A world that places at the first go is the same
            whatever ``restarts``.

    Raises:
        ValueError: ``shape_twins`` with more categories than shapes.
        WorldFileError: The objects do not fit in the workspace after ``restarts``
            restarts.
    """
    if shape_twins and n_categories > len(SHAPES):
        raise ValueError(f"shape_twins: n_categories must be at most {len(SHAPES)} (one "
                         f"category a shape: {', '.join(SHAPES)}), got {n_categories}")
    rng = np.random.default_rng(seed)
    name = name or (f"random_{n_categories}x{copies}_{seed}"
                    + ("_twins" if shape_twins else "") + ("_yaw" if yaw_copies else ""))
    categories: list[tuple[str, float, int, float, str]] = []
    used: set[tuple[str, str, int]] = set()
    if shape_twins:
        size = round(float(rng.uniform(*size_range)), 2)
        intensity = int(rng.integers(50, 131))
        weight = round(float(rng.uniform(0.2, 1.8)), 1)
        texture = str(rng.choice(textures))
        shapes = rng.choice(SHAPES, size=n_categories, replace=False)
        categories = [(str(shape), size, intensity, weight, texture) for shape in shapes]
    while len(categories) < n_categories:
        cat = (str(rng.choice(SHAPES)), round(float(rng.uniform(*size_range)), 2),
               int(rng.integers(50, 131)), round(float(rng.uniform(0.2, 1.8)), 1),
               str(rng.choice(textures)))
        key = (cat[0], cat[4], cat[2] // 20)
        if key in used:
            continue  # keep categories apart in shape/texture or grey level
        used.add(key)
        categories.append(cat)
    source = f"<random world {name}>"
    near: list[tuple[int, str, bool, float | None]] = [
        (c, f"c{c:02d}_{k}", False, _copy_yaw(k, copies) if yaw_copies else None)
        for c in range(n_categories) for k in range(copies)]
    far: list[tuple[int, str, bool, float | None]] = [
        (k % n_categories, f"c{k % n_categories:02d}_far{k // n_categories}", True, None)
        for k in range(out_of_reach)]
    for _ in range(max(restarts, 0) + 1):
        placed = _place(near + far, categories, rng, name, source, min_gap, max_tries)
        if placed is not None:
            return parse_world({"name": name,
                                "objects": [world_to_dict_obj(o) for o in placed]}, source)
    raise WorldFileError(source, "", f"could not place {len(near) + len(far)} objects "
                                     f"without overlap ({max(restarts, 0)} restarts of "
                                     f"{max_tries} attempts each)")


def _place(todo: list[tuple[int, str, bool, float | None]],
           categories: list[tuple[str, float, int, float, str]], rng: np.random.Generator,
           name: str, source: str, min_gap: float, max_tries: int) -> list[ObjectSpec] | None:
    """One placement of every object of ``todo`` (category, name, beyond reach, fixed yaw)
    in turn, at random positions that keep ``min_gap``; None after ``max_tries`` attempts."""
    placed: list[ObjectSpec] = []
    tries = 0
    for c, obj_name, beyond, fixed_yaw in todo:
        shape, size, intensity, weight, texture = categories[c]
        while True:
            tries += 1
            if tries > max_tries:
                return None
            if beyond:
                r = float(rng.uniform(1.25, 1.7))
                bearing = float(rng.uniform(-math.radians(50), math.radians(50)))
            else:
                r = float(rng.uniform(0.45, 1.1))
                bearing = float(rng.uniform(-math.radians(70), math.radians(70)))
            position = [round(r * math.cos(bearing), 3), round(r * math.sin(bearing), 3)]
            yaw = round(float(rng.uniform(0, math.pi)), 2)  # drawn always: same rng stream
            d = {"name": obj_name, "shape": shape, "position": position,
                 "yaw": yaw if fixed_yaw is None else fixed_yaw, "size": size,
                 "intensity": intensity, "weight": weight, "texture": texture}
            try:
                spec = object_from_dict(d, source, f"objects[{len(placed)}]")
                if in_reach(*spec.position) == beyond:
                    continue
                if any(math.dist(o.position, spec.position)
                       < footprint_radius(o.shape, o.size)
                       + footprint_radius(spec.shape, spec.size) + min_gap
                       for o in placed):
                    continue
                parse_world({"name": name, "objects":
                             [world_to_dict_obj(o) for o in placed] + [d]}, source)
            except WorldFileError:
                continue
            placed.append(spec)
            break
    return placed


def _copy_yaw(k: int, copies: int) -> float:
    """Yaw of copy ``k`` of ``copies`` spread evenly over 0 to pi / 2, radians."""
    return 0.0 if copies <= 1 else round(k * (math.pi / 2) / (copies - 1), 2)


def world_to_dict_obj(o: ObjectSpec) -> dict:
    """One object as a world-file dictionary."""
    return world_to_dict(WorldSpec(objects=(o,)))["objects"][0]
