"""The physical backdrop: where its ArUco markers sit, and the shadow window's metres ↔ pixels geometry.

Shared by the virtual camera (:mod:`studio.sim.photo`, which prints the markers) and the footage stage
(:mod:`studio.targets.backdrop`, which finds them in a photograph). Pure compute: numpy and OpenCV only.

Frames (DESIGN §1): **backdrop metres** are (x, y) on the backdrop plane, the light axis at (0, 0), +x the
audience's right and +y up as the audience sees the backdrop from the light's side. **Window pixels** are the shadow
image's continuous (u = col, v = row) coordinates exactly as :meth:`studio.sim.shadow.Rig.to_pixels`: row 0 at the
top (+y), column 0 at the left (-x), pixel ``(r, c)`` covering ``[c, c + 1) × [r, r + 1)`` so its centre is at
``(c + 0.5, r + 0.5)``. OpenCV's own pixel coordinates put a pixel's centre at the integer ``(c, r)``
(:func:`cv_pixels_from_backdrop` gives that matrix, the one ``cv2.warpPerspective`` wants).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    "BackdropLayout",
    "backdrop_from_window_pixels",
    "cv_pixels_from_backdrop",
    "window_corners_m",
    "window_pixels_from_backdrop",
    "window_to_pixels",
    "pixels_to_window",
]

CORNERS = ("top-left", "top-right", "bottom-right", "bottom-left")  # as the audience sees the backdrop


@dataclass(frozen=True)
class BackdropLayout:
    """The backdrop as built: a square sheet with one ArUco marker near each corner, outside the shadow window.

    The markers are printed to read correctly from ``readable_from`` (``"front"``: the light's and audience's side;
    ``"back"``: from behind the sheet, e.g. stuck on its back for a camera behind a translucent backdrop). Their
    ids fix the orientation: ``ids[0]`` is the marker at the audience's top-left, then top-right, bottom-right,
    bottom-left. The defaults keep every marker outside the 0.6 m window (:class:`studio.sim.shadow.Rig`) and on a
    0.95 m sheet.
    """

    dictionary: str = "DICT_4X4_50"  # name of an OpenCV predefined ArUco dictionary (cv2.aruco.DICT_*)
    ids: tuple[int, int, int, int] = (0, 1, 2, 3)  # marker ids at the audience's TL, TR, BR, BL corners
    marker_m: float = 0.08  # printed side of each marker (its black border included), metres
    centre_m: float = 0.40  # marker centres at (±centre_m, ±centre_m) backdrop metres
    size_m: float = 0.95  # side of the square backdrop sheet, centred on the light axis, metres
    readable_from: str = "front"  # "front" (light side) or "back": the side from which the markers read correctly

    def __post_init__(self) -> None:
        if not hasattr(cv2.aruco, self.dictionary):
            raise ValueError(f"unknown ArUco dictionary {self.dictionary!r} (e.g. DICT_4X4_50)")
        if len(self.ids) != 4 or len(set(self.ids)) != 4:
            raise ValueError(f"the layout needs four distinct marker ids, got {self.ids}")
        if not 0 < self.marker_m < self.centre_m * 2:
            raise ValueError("markers must have a positive side smaller than the distance between them")
        if self.centre_m + self.marker_m / 2 > self.size_m / 2:
            raise ValueError(
                f"markers at ±{self.centre_m} m of side {self.marker_m} m do not fit a {self.size_m} m sheet"
            )
        if self.readable_from not in ("front", "back"):
            raise ValueError(f"readable_from must be 'front' or 'back', got {self.readable_from!r}")

    def aruco_dictionary(self) -> cv2.aruco.Dictionary:
        """The OpenCV dictionary object (built in: no download)."""
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    def inner_edge_m(self) -> float:
        """Distance from the light axis to the markers' inner edges, metres (the largest window they leave free)."""
        return self.centre_m - self.marker_m / 2

    def centres_m(self) -> np.ndarray:
        """Marker centres ``(4, 2)`` backdrop metres, in ``ids`` order (TL, TR, BR, BL as the audience sees it)."""
        c = self.centre_m
        return np.array([[-c, c], [c, c], [c, -c], [-c, -c]], dtype=np.float64)

    def marker_corners_m(self, readable_from: str | None = None) -> np.ndarray:
        """Each marker's four corners ``(4 markers, 4 corners, 2)`` in backdrop metres, markers in ``ids`` order and
        corners in OpenCV's ArUco order (the printed marker's own top-left, top-right, bottom-right, bottom-left,
        clockwise as it reads). ``readable_from`` (default: the layout's) says which side the print reads from:
        seen from behind, a marker's own top-left is at the audience's top-right."""
        side = readable_from or self.readable_from
        h = self.marker_m / 2
        sx = 1.0 if side == "front" else -1.0
        own = np.array([[-h * sx, h], [h * sx, h], [h * sx, -h], [-h * sx, -h]])  # TL, TR, BR, BL of the print
        return self.centres_m()[:, None, :] + own[None]

    def marker_image(self, marker_id: int, cells_px: int = 8) -> np.ndarray:
        """The printed marker ``(S, S)`` uint8 (0 black ink, 255 paper) as read from its readable side, S = cells ×
        ``cells_px`` (its black border included)."""
        d = self.aruco_dictionary()
        side = (d.markerSize + 2) * cells_px
        return cv2.aruco.generateImageMarker(d, int(marker_id), side)


def window_corners_m(window_m: float) -> np.ndarray:
    """The shadow window's corners ``(4, 2)`` backdrop metres: TL, TR, BR, BL as the audience sees the backdrop."""
    h = window_m / 2
    return np.array([[-h, h], [h, h], [h, -h], [-h, -h]], dtype=np.float64)


def window_pixels_from_backdrop(window_m: float, resolution: int) -> np.ndarray:
    """``(3, 3)`` homography backdrop metres → continuous window pixels (u, v), as ``Rig.to_pixels``."""
    k = resolution / window_m
    h = window_m / 2
    return np.array([[k, 0.0, h * k], [0.0, -k, h * k], [0.0, 0.0, 1.0]])


def backdrop_from_window_pixels(window_m: float, resolution: int) -> np.ndarray:
    """``(3, 3)`` homography continuous window pixels (u, v) → backdrop metres (the inverse of the one above)."""
    return np.linalg.inv(window_pixels_from_backdrop(window_m, resolution))


def cv_pixels_from_backdrop(window_m: float, resolution: int) -> np.ndarray:
    """``(3, 3)`` homography backdrop metres → OpenCV pixel coordinates of the window image (pixel ``(r, c)``'s
    centre at ``(c, r)``): what ``cv2.warpPerspective`` maps into to sample every window pixel at its centre."""
    shift = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])
    return shift @ window_pixels_from_backdrop(window_m, resolution)


def window_to_pixels(xy_m: np.ndarray, window_m: float, resolution: int) -> np.ndarray:
    """Backdrop ``(..., 2)`` metres → continuous window pixels ``(..., 2)`` (u = col, v = row), as ``Rig.to_pixels``."""
    xy = np.asarray(xy_m, dtype=np.float64)
    h, k = window_m / 2, resolution / window_m
    return np.stack([(xy[..., 0] + h) * k, (h - xy[..., 1]) * k], axis=-1)


def pixels_to_window(uv: np.ndarray, window_m: float, resolution: int) -> np.ndarray:
    """Continuous window pixels ``(..., 2)`` (u = col, v = row) → backdrop ``(..., 2)`` metres; a pixel's centre is
    ``(c + 0.5, r + 0.5)``."""
    p = np.asarray(uv, dtype=np.float64)
    h, k = window_m / 2, resolution / window_m
    return np.stack([p[..., 0] / k - h, h - p[..., 1] / k], axis=-1)
