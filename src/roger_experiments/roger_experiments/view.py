"""What Roger attends to, as one picture per control cycle (issue 10, item 1).

Pure numpy/OpenCV/Pillow: the view node and the Gymnasium environment's ``render`` both
call :func:`compose_view`; :class:`ViewWriter` keeps the pictures of a run as PNG frames and
one animated GIF.

Layout (``scale`` s, retinas H x W): the left retina at (0, 0), the right one at
(0, s*W + margin), each s*H x s*W, then a text panel under both. ROI boundaries (their
bounding boxes are in the left retina) are drawn on the left retina with each ROI's
pre-attentive activation (a bar under the box and ``a``) and its interest (``i``, section
5); the attention window is a thicker box of FOCUS_COLOR with a cross at its centre.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from roger_common.atomic import atomic_write_bytes
from roger_common.errors import ConfigError
from roger_common.types import Roi

#: RGB colour of the attention window.
FOCUS_COLOR: tuple[int, int, int] = (255, 48, 48)
#: RGB colour of the other ROI boundaries.
ROI_COLOR: tuple[int, int, int] = (0, 200, 255)
#: RGB colour of the activation bars.
ACTIVATION_COLOR: tuple[int, int, int] = (80, 255, 80)
#: Pixels between the two retinas.
MARGIN = 8
#: Text panel: height of one line, pixels.
LINE_HEIGHT = 14
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_TEXT_COLOR = (235, 235, 235)
_PANEL_BG = (24, 24, 24)
_SEPARATOR = (96, 96, 96)
#: The Table 2 counters shown, with their short labels.
_COUNTER_LABELS: tuple[tuple[str, str], ...] = (
    ("cycles", "cycle"), ("attention_shifts", "shifts"), ("improvements", "improv"),
    ("positive_identifications", "ids"), ("new_objects", "new"), ("remaps", "remaps"),
    ("map_updates", "maps"))


def retina_rgb(img: np.ndarray) -> np.ndarray:
    """A retina (float in [0, 1], or uint8) as an RGB uint8 image.

    Raises:
        ValueError: The image is not 2-D.
    """
    a = np.asarray(img)
    if a.ndim != 2:
        raise ValueError(f"a retina is a 2-D image, got shape {a.shape}")
    if a.dtype != np.uint8:
        a = np.nan_to_num(a.astype(np.float32), nan=0.0)
        a = (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return np.repeat(a[:, :, None], 3, axis=2)


def panel_lines(state_bits: str, action_name: str, counters: Mapping[str, int],
                rois: Sequence[Roi], focus_roi: int | None,
                interests: Mapping[int, float] | None) -> list[str]:
    """The text panel's lines: FSM state and action, the counters, the ROIs by activation."""
    lines = [f"state nim={state_bits or '---'}   action: {action_name or '-'}"]
    lines.append("  ".join(f"{label} {int(counters.get(key, 0))}"
                           for key, label in _COUNTER_LABELS))
    ranked = sorted(rois, key=lambda r: -float(r.activation))
    cells = []
    for roi in ranked[:4]:
        mark = "*" if roi.roi_id == focus_roi else ""
        cell = f"{mark}#{roi.roi_id} a{roi.activation:.2f}"
        if interests is not None and roi.roi_id in interests:
            cell += f" i{interests[roi.roi_id]:.2f}"
        cells.append(cell)
    lines.append("ROIs: " + ("  ".join(cells) if cells else "none"))
    return lines


def _scaled(img: np.ndarray, scale: int) -> np.ndarray:
    if scale == 1:
        return img
    return cv2.resize(img, (img.shape[1] * scale, img.shape[0] * scale),
                      interpolation=cv2.INTER_NEAREST)


def _box(canvas: np.ndarray, bbox: Sequence[int], scale: int, color: tuple[int, int, int],
         thickness: int) -> tuple[int, int, int, int]:
    """Draw bbox (u0, v0, u1, v1; ends exclusive) scaled; returns the drawn corners."""
    u0, v0, u1, v1 = (int(v) for v in bbox)
    x0, y0 = u0 * scale, v0 * scale
    x1, y1 = max(x0, u1 * scale - 1), max(y0, v1 * scale - 1)
    cv2.rectangle(canvas, (x0, y0), (x1, y1), color, thickness)
    return x0, y0, x1, y1


def focus_roi_id(rois: Sequence[Roi], focus_bbox: Sequence[int] | None) -> int | None:
    """The ROI whose box overlaps the attention window most; None without a window."""
    if focus_bbox is None:
        return None
    fu0, fv0, fu1, fv1 = focus_bbox
    best, best_area = None, 0
    for roi in rois:
        u0, v0, u1, v1 = roi.bbox
        area = max(0, min(u1, fu1) - max(u0, fu0)) * max(0, min(v1, fv1) - max(v0, fv0))
        if area > best_area:
            best, best_area = roi.roi_id, area
    return best


def compose_view(left: np.ndarray, right: np.ndarray, rois: Sequence[Roi],
                 focus_bbox: Sequence[int] | None, state_bits: str, action_name: str,
                 counters: Mapping[str, int], interests: Mapping[int, float] | None = None,
                 scale: int = 1) -> np.ndarray:
    """Both retinas side by side with ROIs, attention window and a text panel.

    Args:
        left, right: Retinas, float in [0, 1] (or uint8), shape (H, W) each.
        rois: ROIs of the left retina (their ``bbox`` and ``activation`` are drawn).
        focus_bbox: The attention window (u0, v0, u1, v1) in the left retina, ends
            exclusive; None when nothing is in focus.
        state_bits: FSM state "nim" (section 4.2), e.g. "010".
        action_name: The last action, e.g. "visual_improvement".
        counters: Table 2 counters by name (``RunCounters.as_dict()`` keys).
        interests: Interest of each ROI by ``roi_id`` (section 5), when known.
        scale: Integer magnification of the retinas (text is not scaled).

    Returns:
        RGB uint8 image of shape (s*H + panel, 2*s*W + MARGIN, 3), s = ``scale``.

    Raises:
        ValueError: Retinas of different shapes, or ``scale`` < 1.
    """
    if scale < 1:
        raise ValueError(f"scale must be >= 1, got {scale}")
    lrgb, rrgb = retina_rgb(left), retina_rgb(right)
    if lrgb.shape != rrgb.shape:
        raise ValueError(f"left and right retinas differ: {lrgb.shape} vs {rrgb.shape}")
    h, w = lrgb.shape[0] * scale, lrgb.shape[1] * scale
    focus = focus_roi_id(rois, focus_bbox)
    lines = panel_lines(state_bits, action_name, counters, rois, focus, interests)
    panel_h = LINE_HEIGHT * len(lines) + 6
    canvas = np.zeros((h + panel_h, 2 * w + MARGIN, 3), np.uint8)
    canvas[h:, :] = _PANEL_BG
    canvas[:h, w:w + MARGIN] = _SEPARATOR
    left_view = np.ascontiguousarray(_scaled(lrgb, scale))
    for roi in rois:
        x0, y0, x1, y1 = _box(left_view, roi.bbox, scale, ROI_COLOR, 1)
        bar = round((x1 - x0) * float(np.clip(roi.activation, 0.0, 1.0)))
        if bar > 0 and y1 + 2 < h:
            cv2.line(left_view, (x0, y1 + 2), (x0 + bar, y1 + 2), ACTIVATION_COLOR, 1)
        if scale > 1:
            label = f"{roi.roi_id}:{roi.activation:.2f}"
            cv2.putText(left_view, label, (x0, max(8, y0 - 2)), _FONT, 0.3, ROI_COLOR, 1,
                        cv2.LINE_AA)
    if focus_bbox is not None:
        x0, y0, x1, y1 = _box(left_view, focus_bbox, scale, FOCUS_COLOR, 2 if scale > 1 else 1)
        cx, cy = (x0 + x1) // 2, (y0 + y1) // 2
        cv2.drawMarker(left_view, (cx, cy), FOCUS_COLOR, cv2.MARKER_CROSS, 4 * scale, 1)
    canvas[:h, :w] = left_view
    canvas[:h, w + MARGIN:] = _scaled(rrgb, scale)
    for i, line in enumerate(lines):
        cv2.putText(canvas, line, (4, h + LINE_HEIGHT * (i + 1)), _FONT, 0.38, _TEXT_COLOR, 1,
                    cv2.LINE_AA)
    return canvas


class ViewWriter:
    """Writes each view as ``frame_00001.png`` ... and, at ``close()``, ``view.gif``.

    Attributes:
        out_dir: The folder (created if missing).
        fps: Frames per second of the GIF.
        frames: Paths of the PNG frames written so far.
    """

    def __init__(self, out_dir: Path, fps: float = 4.0, gif_name: str = "view.gif") -> None:
        """Create the folder; nothing is written until the first frame.

        Raises:
            ConfigError: ``fps`` is not in (0, 100].
        """
        if not 0.0 < fps <= 100.0:
            raise ConfigError(f"ViewWriter.fps must be in (0, 100], got {fps!r}")
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.fps = fps
        self.gif_name = gif_name
        self.frames: list[Path] = []
        self._closed = False

    def write(self, view: np.ndarray) -> Path:
        """Save one RGB uint8 view as the next PNG frame; returns its path."""
        if self._closed:
            raise RuntimeError("ViewWriter.write after close()")
        path = self.out_dir / f"frame_{len(self.frames) + 1:05d}.png"
        buf = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(view, np.uint8), "RGB").save(buf, format="PNG")
        atomic_write_bytes(path, buf.getvalue())
        self.frames.append(path)
        return path

    def close(self) -> Path | None:
        """Write the animated GIF of every frame (atomically); returns it, None if no frame.

        Calling it again does nothing.
        """
        if self._closed:
            return None
        self._closed = True
        if not self.frames:
            return None
        first, *rest = (Image.open(p) for p in self.frames)
        buf = io.BytesIO()
        first.save(buf, format="GIF", save_all=True, append_images=rest,
                   duration=round(1000.0 / self.fps), loop=0)
        for im in (first, *rest):
            im.close()
        gif = self.out_dir / self.gif_name
        atomic_write_bytes(gif, buf.getvalue())
        return gif


def interests_by_roi(rois: Sequence[Roi],
                     entries: Sequence[tuple[tuple[float, float, float], float]],
                     radius: float) -> dict[int, float]:
    """Interest of each ROI: that of the nearest spatial-map entry within ``radius`` metres.

    The spatial map associates ROIs with its entries by position (section 5's interest
    belongs to an entry); the view does the same to label each ROI.

    Args:
        rois: ROIs of one frame.
        entries: (position, interest) of every map entry.
        radius: Largest distance for a ROI to be an entry (the map's association radius).
    """
    out: dict[int, float] = {}
    if not entries:
        return out
    positions = np.asarray([p for p, _ in entries], float)
    for roi in rois:
        d = np.linalg.norm(positions - np.asarray(roi.position, float), axis=1)
        i = int(np.argmin(d))
        if d[i] <= radius:
            out[roi.roi_id] = float(entries[i][1])
    return out
