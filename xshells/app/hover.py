"""Joint labels on hover: the pointer's place in the 3D view, relayed to the server, and the joint under it.

viser 1.1 reports clicks and rectangle selections in the scene, but no pointer
motion, and its 3D GUI containers do not render in its shipped client (tried
in headless Chromium: the container's elements never reach the page). So the
page relays the pointer itself: a small script in an HTML element of the
panel listens (passively: clicks and drags still reach the scene) for pointer
moves over the 3D canvas and writes them, at most 20 times a second, into a
hidden text field, which viser sends to the server like any edit. The server
finds the joint nearest the pointer on the screen with that client's camera
(:func:`pick_on_screen`) and labels it.

Only the relay runs in the browser; what is picked, and how, is computed here
and tested without a browser.
"""
from __future__ import annotations

import numpy as np

HOVER_RADIUS_PX = 14.0  # a joint this close to the pointer on the screen is the one under it
RELAY_INTERVAL_MS = 50  # the page sends at most 20 pointer positions a second, the last one always

# Runs once per page (the flag guards against React mounting the element again). It finds the first text
# input after its marker element, hides that input's row, and writes "x y width height" into it: the pointer
# in normalized device coordinates (x right, y up, both in [-1, 1]) and the canvas size in CSS pixels, or ""
# when the pointer leaves the canvas. The native value setter and an "input" event are what React's
# onChange (and so viser's update message) listens to.
_RELAY_JS = """
if (!window.__xshellsHover) { window.__xshellsHover = 1;
  const field = () => { const m = document.querySelector('[data-xshells-hover]'); if (!m) return null;
    for (const i of document.querySelectorAll('input'))
      if (m.compareDocumentPosition(i) & Node.DOCUMENT_POSITION_FOLLOWING) return i;
    return null; };
  const hide = (i) => { let row = i; while (row.parentElement && !row.parentElement.contains(
      document.querySelector('[data-xshells-hover]'))) row = row.parentElement;
    row.setAttribute('data-xshells-hidden', ''); };
  const setValue = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, 'value').set;
  let sent = null, last = 0, timer = null;
  const send = (msg) => { const i = field(); if (!i) return; hide(i); if (msg === sent) return; sent = msg;
    setValue.call(i, msg); i.dispatchEvent(new Event('input', { bubbles: true })); };
  const later = (msg) => { clearTimeout(timer); const now = performance.now();
    if (now - last >= INTERVAL) { last = now; send(msg); }
    else timer = setTimeout(() => { last = performance.now(); send(msg); }, INTERVAL - (now - last)); };
  document.addEventListener('pointermove', (e) => {
    const c = e.target;
    if (!(c instanceof HTMLCanvasElement)) { if (sent) later(''); return; }
    const r = c.getBoundingClientRect();
    later(((e.clientX - r.left) / r.width * 2 - 1).toFixed(5) + ' ' + (1 - (e.clientY - r.top) / r.height * 2).toFixed(5)
          + ' ' + r.width.toFixed(1) + ' ' + r.height.toFixed(1)); }, { passive: true });
  document.addEventListener('pointerout', (e) => { if (!e.relatedTarget) later(''); });
  const i = field(); if (i) hide(i); }
"""


def decimals(span: float) -> int:
    """Decimals that resolve 1/10 000 of ``span``: the coordinates as a drawing gives them, in the design's unit.

    Four significant digits read "(2.078e+04, -7852)" for the manta ray's
    joint 81 (a 2317 mm span, 20 m from the origin); one decimal reads
    "(20781.3, -7852.4)".
    """
    span = float(span)
    return int(np.clip(np.ceil(-np.log10(1e-4 * span)), 0, 12)) if np.isfinite(span) and span > 0 else 4


def flat_label(v: int, xy, span: float, to_file: tuple | None = None) -> str:
    """The hover label of joint ``v`` of the flat layout: its coordinates in the file opened.

    ``to_file`` ``(A, b)`` maps layout coordinates to the file's (``xy @ A + b``) where the app re-centred
    the design (one drawn off z = 0, or with round-off out of it); without it the layout's are the file's.
    """
    d = decimals(span)
    if to_file is not None:
        x, y, z = np.asarray(xy, float) @ to_file[0] + to_file[1]
        z = 0.0 if abs(z) < 0.5 * 10.0 ** -d else z  # no "-0.0" from round-off
        return f"joint {v}  ({x:.{d}f}, {y:.{d}f}, {z:.{d}f})"
    return f"joint {v}  ({xy[0]:.{d}f}, {xy[1]:.{d}f})"


def height_label(v: int, z: float, span: float) -> str:
    """The hover label of joint ``v`` of a deployed state: its height above the lowest joint."""
    return f"joint {v}  (height {z:.{decimals(span)}f})"


def relay_html() -> str:
    """The panel element that relays the pointer: a marker, a style that hides the field, and the script.

    The script runs from an image's ``onerror`` (an image with an empty data URL always fails), since a
    ``<script>`` element set as inner HTML does not run.
    """
    js = " ".join(line.strip() for line in _RELAY_JS.strip().splitlines()).replace("INTERVAL", str(RELAY_INTERVAL_MS))
    return ('<div data-xshells-hover></div><style>[data-xshells-hidden]{display:none !important}</style>'
            f'<img alt="" src="data:," style="display:none" onerror="{js.replace(chr(34), "&quot;")}">')


def parse_pointer(text: str) -> tuple[np.ndarray, float, float] | None:
    """``"x y width height"`` from the page → (pointer in normalized device coordinates, width, height), or None.

    None for an empty or malformed message (the pointer left the canvas, or the field was typed into).
    """
    parts = str(text).split()
    if len(parts) != 4:
        return None
    try:
        x, y, w, h = (float(p) for p in parts)
    except ValueError:
        return None
    if not (np.isfinite([x, y, w, h]).all() and w > 0 and h > 0 and abs(x) <= 1.5 and abs(y) <= 1.5):
        return None
    return np.array([x, y]), w, h


def project(points: np.ndarray, position, wxyz, fov: float, aspect: float) -> tuple[np.ndarray, np.ndarray]:
    """Scene points → normalized device coordinates of a viser camera, and whether each lies in front of it.

    Parameters
    ----------
    points : (n, 3) scene coordinates.
    position : (3,) the camera's position.
    wxyz : (4,) its orientation, camera to scene, in viser's (OpenCV) convention: +z looks forward, +y down.
    fov : vertical field of view in radians.
    aspect : width / height.

    Returns
    -------
    ndc : (n, 2) x right and y up, in [-1, 1] across the view.
    in_front : (n,) bool.
    """
    w, x, y, z = np.asarray(wxyz, float) / np.linalg.norm(wxyz)
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    q = (np.asarray(points, float) - np.asarray(position, float)) @ R  # camera coordinates, R^T (p - c)
    depth = q[:, 2]
    in_front = depth > 1e-9
    t = np.tan(0.5 * fov)
    safe = np.where(in_front, depth, 1.0)
    ndc = np.c_[q[:, 0] / safe / (t * aspect), -q[:, 1] / safe / t]
    return ndc, in_front


def pick_on_screen(points: np.ndarray, pointer: np.ndarray, width: float, height: float, camera: dict,
                   radius_px: float = HOVER_RADIUS_PX) -> int | None:
    """The index of the point nearest the pointer on the screen within ``radius_px``, else None.

    ``camera`` holds ``position``, ``wxyz``, ``fov`` (vertical, radians); the aspect is the canvas's
    ``width / height`` (CSS pixels). Of points equally near on the screen, the one nearer the camera wins.
    """
    points = np.asarray(points, float).reshape(-1, 3)
    if not len(points):
        return None
    ndc, in_front = project(points, camera["position"], camera["wxyz"], float(camera["fov"]), width / height)
    d_px = np.hypot((ndc[:, 0] - pointer[0]) * 0.5 * width, (ndc[:, 1] - pointer[1]) * 0.5 * height)
    d_px[~in_front] = np.inf
    k = int(np.argmin(d_px))
    return k if d_px[k] <= radius_px else None
