"""Face models driven by ARKit blendshape weights, and the project's own built-in parametric head.

A ``FaceModel`` is a few ``Part`` meshes (skin, mouth cavity, teeth, tongue, eyes), each with rest
vertices, triangles, per-vertex colours and one displacement field per ARKit blendshape: the posed
vertices are ``rest + sum_k w_k * delta_k`` (linear blendshapes, as ARKit and glTF morph targets work),
followed by the head rotation (HeadYaw/HeadPitch/HeadRoll, taken as radians) about the neck pivot.

The built-in head (``builtin_face``) is an ellipsoid with a nose, lips, brows and eyes. Its mouth is a
real slit (the row of vertices on the lip line is doubled, upper and lower lip unconnected between the
corners), so jawOpen shows the dark cavity and the teeth. Every one of the 52 ARKit shapes has a field
(the 32 pronunciation channels on lips, jaw and cheeks; eyes, brows, nose and tongue too). Units: the
head is about 2 units tall, +y up, +z forward (towards the viewer), the character's left at +x.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from capture.channels import ARKIT61

SKIN = (224, 172, 140)
LIPS = (178, 84, 84)
BROW = (92, 64, 48)
CAVITY = (48, 14, 16)
TEETH = (240, 238, 226)
TONGUE = (196, 92, 100)
EYE_WHITE = (242, 242, 238)
IRIS = (40, 64, 88)

_IDX = {n: i for i, n in enumerate(ARKIT61)}


@dataclass
class Part:
    """One mesh of a face: rest vertices (V, 3), triangles (F, 3), colours (V, 3) uint8, and
    ``deltas``: ARKit channel index → displacement (V, 3) at weight 1."""

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    colors: np.ndarray
    deltas: dict[int, np.ndarray] = field(default_factory=dict)
    smooth: bool = True

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int64)
        self.colors = np.ascontiguousarray(np.broadcast_to(self.colors, self.vertices.shape), dtype=np.uint8)
        self.deltas = {k: np.asarray(v, dtype=np.float32) for k, v in self.deltas.items() if np.any(v)}


@dataclass
class FaceModel:
    """A face to render: parts, the neck pivot for head rotation, and where the camera looks from."""

    name: str
    parts: list[Part]
    pivot: np.ndarray  # (3,) centre of the head rotation
    camera_position: tuple[float, float, float]
    camera_focus: tuple[float, float, float]
    view_angle: float = 30.0  # degrees
    head_rotation: bool = True
    extra: dict = field(default_factory=dict)  # e.g. a glTF's mapped and unmapped target names

    @property
    def channels(self) -> list[str]:
        """ARKit names that move at least one vertex."""
        used = set().union(*(p.deltas.keys() for p in self.parts))
        return [ARKIT61[i] for i in sorted(used)]

    def pose(self, weights: np.ndarray) -> list[np.ndarray]:
        """Vertices of every part for ``weights`` (61,) in ARKIT61 order (NaN counts as 0)."""
        w = np.nan_to_num(np.asarray(weights, dtype=np.float64), nan=0.0)
        out = []
        for part in self.parts:
            v = part.vertices.copy()
            for k, d in part.deltas.items():
                if abs(w[k]) > 1e-6:
                    v += w[k] * d
            out.append(v)
        if self.head_rotation:
            rot = head_rotation_matrix(w[_IDX["headYaw"]], w[_IDX["headPitch"]], w[_IDX["headRoll"]])
            if not np.allclose(rot, np.eye(3)):
                out = [(v - self.pivot) @ rot.T + self.pivot for v in out]
        return out


def head_rotation_matrix(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Rotation (3, 3) for yaw about +y, pitch about +x (nodding down is positive), roll about +z."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return ry @ rx @ rz


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3)."""
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    fn = np.cross(b - a, c - a)
    n = np.zeros_like(vertices)
    for i in range(3):
        for axis in range(3):
            n[:, axis] += np.bincount(triangles[:, i], fn[:, axis], minlength=len(vertices))
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(norm > 0, norm, 1.0)


# -- the built-in head ----------------------------------------------------------------------------
A, B, C = 0.78, 1.0, 0.86  # ellipsoid semi-axes: width, height, depth
MOUTH_EL = -0.42  # elevation (rad) of the lip line
MOUTH_HALF = 0.36  # half-width of the mouth as an azimuth (rad)
HINGE = np.array([0.0, -0.02, -0.18])  # jaw hinge (rotation about the x axis through it)
JAW_ANGLE = 0.40  # jaw rotation (rad) at jawOpen = 1
EYE_AZ, EYE_EL, EYE_R = 0.37, 0.13, 0.115


def _gauss(x: np.ndarray, sigma: float) -> np.ndarray:
    return np.exp(-0.5 * (x / sigma) ** 2)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def _surface(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Rest skin: the ellipsoid with a nose ridge and a fuller chin pushed out along +z."""
    x = A * np.cos(phi) * np.sin(theta)
    y = B * np.sin(phi)
    z = C * np.cos(phi) * np.cos(theta)
    front = np.clip(np.cos(theta), 0, None)
    nose = 0.20 * _gauss(theta, 0.085) * _gauss(phi + 0.14, 0.13) * front
    nose += 0.05 * _gauss(theta, 0.06) * _gauss(phi - 0.05, 0.12)  # bridge
    chin = 0.05 * _gauss(theta, 0.3) * _gauss(phi + 0.78, 0.14)
    lips = 0.035 * _gauss(theta, MOUTH_HALF * 0.8) * _gauss(phi - MOUTH_EL, 0.07)
    sockets = (
        -0.05 * (_gauss(theta - EYE_AZ, 0.14) + _gauss(theta + EYE_AZ, 0.14)) * _gauss(phi - EYE_EL, 0.1)
    )
    z = z + nose + chin + lips + sockets * front
    return np.stack([x, y, z], axis=-1)


def _skin_grid(n_az: int, n_el: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, triangles, per-vertex (theta, phi) and side (+1 upper lip/head, -1 lower/jaw)."""
    el = np.linspace(-np.pi / 2 * 0.97, np.pi / 2 * 0.97, n_el)
    el = np.sort(np.concatenate([el[np.abs(el - MOUTH_EL) > 0.02], [MOUTH_EL]]))
    m = int(np.flatnonzero(el == MOUTH_EL)[0])
    rows = np.concatenate([el[: m + 1], [MOUTH_EL], el[m + 1 :]])  # the lip line twice
    side_rows = np.where(np.arange(rows.size) <= m, -1, 1)
    az = np.linspace(-np.pi, np.pi, n_az, endpoint=False)
    theta, phi = np.meshgrid(az, rows)  # (rows, n_az)
    side = np.broadcast_to(side_rows[:, None], theta.shape)
    verts = _surface(theta, phi).reshape(-1, 3)
    nr = rows.size
    tris = []
    for r in range(nr - 1):
        for c in range(n_az):
            c2 = (c + 1) % n_az
            if r == m and abs(az[c]) < MOUTH_HALF and abs(az[c2]) < MOUTH_HALF and c2 != 0:
                continue  # the mouth slit: upper and lower lip are not connected between the corners
            a, b = r * n_az + c, r * n_az + c2
            d, e = (r + 1) * n_az + c, (r + 1) * n_az + c2
            tris += [(a, b, e), (a, e, d)]
    # Close the poles with fans.
    bottom = len(verts)
    top = bottom + 1
    verts = np.vstack([verts, [[0, -B, 0.0]], [[0, B, 0.0]]])
    for c in range(n_az):
        c2 = (c + 1) % n_az
        tris.append((bottom, c2, c))
        tris.append((top, (nr - 1) * n_az + c, (nr - 1) * n_az + c2))
    th = np.concatenate([theta.ravel(), [0.0, 0.0]])
    ph = np.concatenate([phi.ravel(), [-np.pi / 2, np.pi / 2]])
    sd = np.concatenate([side.ravel(), [-1, 1]])
    return verts, np.array(tris), np.stack([th, ph], axis=1), sd


def _ellipsoid(center, radii, n_az: int = 24, n_el: int = 16) -> tuple[np.ndarray, np.ndarray]:
    az = np.linspace(-np.pi, np.pi, n_az, endpoint=False)
    el = np.linspace(-np.pi / 2, np.pi / 2, n_el)[1:-1]
    t, p = np.meshgrid(az, el)
    v = np.stack([np.cos(p) * np.sin(t), np.sin(p), np.cos(p) * np.cos(t)], -1).reshape(-1, 3)
    v = np.vstack([v, [[0, -1, 0], [0, 1, 0]]]) * np.asarray(radii) + np.asarray(center)
    nr = el.size
    tris = []
    for r in range(nr - 1):
        for c in range(n_az):
            c2 = (c + 1) % n_az
            a, b, d, e = r * n_az + c, r * n_az + c2, (r + 1) * n_az + c, (r + 1) * n_az + c2
            tris += [(a, b, e), (a, e, d)]
    bot, top = nr * n_az, nr * n_az + 1
    for c in range(n_az):
        c2 = (c + 1) % n_az
        tris += [(bot, c2, c), (top, (nr - 1) * n_az + c, (nr - 1) * n_az + c2)]
    return v, np.array(tris)


def _arc_band(radius, z0, half_angle, y0, y1, n: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """A curved strip (teeth) around the y axis: angle ±half_angle, from height y0 to y1."""
    t = np.linspace(-half_angle, half_angle, n)
    lo = np.stack([radius * np.sin(t), np.full(n, y0), z0 + radius * np.cos(t)], -1)
    hi = lo.copy()
    hi[:, 1] = y1
    v = np.vstack([lo, hi])
    tris = []
    for i in range(n - 1):
        tris += [(i, i + 1, n + i + 1), (i, n + i + 1, n + i)]
    return v, np.array(tris)


def _jaw_target(v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Displacement of rotating points about the hinge by JAW_ANGLE * w (opening: chin down and back)."""
    ang = JAW_ANGLE * w
    p = v - HINGE
    c, s = np.cos(ang), np.sin(ang)
    y = c * p[:, 1] - s * p[:, 2]
    z = s * p[:, 1] + c * p[:, 2]
    return np.stack([np.zeros_like(y), y - p[:, 1], z - p[:, 2]], -1)


def _skin_fields(
    v: np.ndarray, theta: np.ndarray, phi: np.ndarray, side: np.ndarray
) -> dict[str, np.ndarray]:
    lower = side < 0
    upper = ~lower
    dphi = phi - MOUTH_EL
    x = v[:, 0]
    front = _smoothstep(np.cos(theta) * 2)
    opening = np.clip(1 - (theta / MOUTH_HALF) ** 2, 0, None) ** 0.6
    lateral = 1 / (1 + np.exp((np.abs(theta) - 1.15) / 0.12))
    below = _smoothstep(-dphi / 0.3)
    w_jaw = np.where(lower, opening + (lateral - opening) * below, 0.0)
    w_jaw = np.where(lower & (phi < -1.2), lateral, w_jaw)
    jaw = _jaw_target(v, w_jaw)
    lips = np.exp(-((theta / (MOUTH_HALF * 1.12)) ** 4)) * _gauss(dphi, 0.07) * front
    lips_wide = np.exp(-((theta / (MOUTH_HALF * 1.5)) ** 4)) * _gauss(dphi, 0.14) * front
    up, lo = lips * upper, lips * lower

    def corner(sign: float, s_t: float = 0.13, s_p: float = 0.1) -> np.ndarray:
        return _gauss(theta - sign * MOUTH_HALF, s_t) * _gauss(dphi, s_p) * front

    def half(sign: float) -> np.ndarray:
        return 1 / (1 + np.exp(-sign * theta / 0.08))

    def vec(dx=0.0, dy=0.0, dz=0.0, w=1.0) -> np.ndarray:
        return (
            np.stack(
                [np.broadcast_to(dx, x.shape), np.broadcast_to(dy, x.shape), np.broadcast_to(dz, x.shape)], -1
            )
            * np.asarray(w)[:, None]
        )

    normal = v / np.array([A * A, B * B, C * C])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    f: dict[str, np.ndarray] = {
        "jawOpen": jaw,
        "jawForward": vec(dz=0.09, w=w_jaw),
        "jawLeft": vec(dx=0.08, w=w_jaw),
        "jawRight": vec(dx=-0.08, w=w_jaw),
        "mouthClose": -jaw * (lips_wide * lower)[:, None] + vec(dy=-0.008, w=up),
        "mouthFunnel": vec(dz=0.06, w=lips_wide)
        + vec(dx=-0.3 * x, w=lips)
        + vec(dy=0.03, w=up)
        + vec(dy=-0.03, w=lo),
        "mouthPucker": vec(dz=0.09, w=lips_wide)
        + vec(dx=-0.5 * x, w=lips_wide)
        + vec(dy=-0.4 * dphi * B, w=lips),
    }
    for name, sign in (("Left", 1.0), ("Right", -1.0)):
        c = corner(sign)
        cw = corner(sign, 0.22, 0.16)
        h = half(sign)
        f["mouth" + name] = vec(dx=sign * 0.07, w=lips_wide)
        f["mouthSmile" + name] = vec(dx=sign * 0.04, dy=0.06, dz=-0.02, w=cw)
        f["mouthFrown" + name] = vec(dy=-0.055, w=cw)
        f["mouthDimple" + name] = vec(dx=sign * 0.02, dz=-0.045, w=c)
        f["mouthStretch" + name] = vec(dx=sign * 0.065, dy=-0.02, w=cw)
        f["mouthPress" + name] = vec(dy=-0.012, dz=-0.012, w=up * h) + vec(dy=0.012, dz=-0.012, w=lo * h)
        f["mouthLowerDown" + name] = vec(dy=-0.05, w=lo * h)
        f["mouthUpperUp" + name] = vec(dy=0.05, w=up * h)
        f["cheekSquint" + name] = vec(dy=0.04, w=_gauss(theta - sign * 0.48, 0.16) * _gauss(phi + 0.02, 0.12))
        f["noseSneer" + name] = vec(
            dy=0.035, dz=0.01, w=_gauss(theta - sign * 0.11, 0.07) * _gauss(phi + 0.12, 0.1)
        )
        f["browDown" + name] = vec(dy=-0.045, w=_gauss(theta - sign * 0.32, 0.22) * _gauss(phi - 0.33, 0.09))
        f["browOuterUp" + name] = vec(dy=0.05, w=_gauss(theta - sign * 0.5, 0.14) * _gauss(phi - 0.33, 0.09))
    f["mouthRollLower"] = vec(dy=0.015, dz=-0.04, w=lo)
    f["mouthRollUpper"] = vec(dy=-0.015, dz=-0.04, w=up)
    f["mouthShrugLower"] = vec(
        dy=0.04, w=lips_wide * lower + 0.6 * _gauss(theta, 0.3) * _gauss(phi + 0.7, 0.15)
    )
    f["mouthShrugUpper"] = vec(dy=0.03, w=up)
    f["browInnerUp"] = vec(dy=0.05, w=_gauss(np.abs(theta) - 0.13, 0.1) * _gauss(phi - 0.33, 0.09))
    cheeks = (_gauss(theta - 0.55, 0.2) + _gauss(theta + 0.55, 0.2)) * _gauss(phi + 0.28, 0.18)
    f["cheekPuff"] = normal * (0.09 * cheeks)[:, None]
    return f


def _lower_rigid(v: np.ndarray, lower: np.ndarray) -> dict[str, np.ndarray]:
    """Jaw fields of an inner part whose ``lower`` vertices move rigidly with the jaw."""
    w = lower.astype(np.float64)
    z = np.zeros_like(v)
    f = {"jawOpen": _jaw_target(v, w), "jawForward": z.copy(), "jawLeft": z.copy(), "jawRight": z.copy()}
    f["jawForward"][:, 2] = 0.09 * w
    f["jawLeft"][:, 0] = 0.08 * w
    f["jawRight"][:, 0] = -0.08 * w
    return f


def _eye_fields(v: np.ndarray, center: np.ndarray, sign: float, iris: bool) -> dict[str, np.ndarray]:
    """Blink squashes the eye vertically into the socket, wide stretches it; look rotates the iris."""
    name = "Left" if sign > 0 else "Right"
    rel = v - center
    f: dict[str, np.ndarray] = {}
    squash = np.zeros_like(v)
    squash[:, 1] = -0.94 * rel[:, 1]
    f["eyeBlink" + name] = squash
    f["eyeSquint" + name] = 0.3 * squash
    f["eyeWide" + name] = -0.25 * squash
    if iris:
        a = 0.35  # rad at weight 1
        for look, axis, s in (("Up", 0, -1.0), ("Down", 0, 1.0), ("In", 1, -sign), ("Out", 1, sign)):
            ang = a * s
            c, si = np.cos(ang), np.sin(ang)
            r = rel.copy()
            if axis == 0:  # about x: up/down
                r[:, 1], r[:, 2] = c * rel[:, 1] - si * rel[:, 2], si * rel[:, 1] + c * rel[:, 2]
            else:  # about y: in/out
                r[:, 0], r[:, 2] = c * rel[:, 0] + si * rel[:, 2], -si * rel[:, 0] + c * rel[:, 2]
            f["eyeLook" + look + name] = r - rel
    return f


def _deltas(fields: dict[str, np.ndarray]) -> dict[int, np.ndarray]:
    return {_IDX[k]: v for k, v in fields.items()}


def builtin_face(detail: int = 1) -> FaceModel:
    """The project's parametric head (no asset needed). ``detail`` scales the mesh resolution."""
    n_az, n_el = 112 * detail, 84 * detail
    v, tris, tp, side = _skin_grid(n_az, n_el)
    theta, phi = tp[:, 0], tp[:, 1]
    colors = np.tile(np.array(SKIN, np.float64), (len(v), 1))
    lipw = np.exp(-((theta / (MOUTH_HALF * 1.08)) ** 4)) * _gauss(
        phi - MOUTH_EL - np.where(side > 0, 0.025, -0.03), 0.03
    )
    lipw = np.clip(lipw * 1.6, 0, 1) * (np.cos(theta) > 0)
    colors += (np.array(LIPS) - colors) * lipw[:, None]
    browm = (_gauss(np.abs(theta) - 0.33, 0.13) * _gauss(phi - 0.33, 0.025)) > 0.5
    colors[browm] = BROW
    skin = Part("skin", v, tris, colors.astype(np.uint8), _deltas(_skin_fields(v, theta, phi, side)))
    parts = [skin]

    y_m = B * np.sin(MOUTH_EL)
    z_front = C * np.cos(MOUTH_EL)
    cav_c = np.array([0.0, y_m - 0.02, z_front - 0.32])
    cv, ct = _ellipsoid(cav_c, (0.26, 0.2, 0.28))
    parts.append(Part("cavity", cv, ct, CAVITY, _deltas(_lower_rigid(cv, cv[:, 1] < y_m)), smooth=True))
    tv, tt = _arc_band(0.26, z_front - 0.33, 0.55, y_m - 0.07, y_m + 0.02)
    parts.append(Part("teeth_upper", tv, tt, TEETH))
    lv, lt = _arc_band(0.245, z_front - 0.335, 0.5, y_m - 0.04, y_m + 0.01)
    parts.append(Part("teeth_lower", lv, lt, TEETH, _deltas(_lower_rigid(lv, np.ones(len(lv), bool)))))
    gv, gt = _ellipsoid((0.0, y_m - 0.07, z_front - 0.24), (0.13, 0.04, 0.17), 20, 10)
    tongue = _lower_rigid(gv, np.ones(len(gv), bool))
    tongue["tongueOut"] = np.tile([0.0, 0.01, 0.22], (len(gv), 1))
    parts.append(Part("tongue", gv, gt, TONGUE, _deltas(tongue)))

    for sign in (1.0, -1.0):
        th, ph = sign * EYE_AZ, EYE_EL
        surf = _surface(np.array(th), np.array(ph))
        normal = surf / np.array([A * A, B * B, C * C])
        normal /= np.linalg.norm(normal)
        center = surf - normal * (EYE_R * 0.35)
        ev, et = _ellipsoid(center, (EYE_R, EYE_R, EYE_R), 28, 18)
        parts.append(
            Part(
                "eye_" + ("left" if sign > 0 else "right"),
                ev,
                et,
                EYE_WHITE,
                _deltas(_eye_fields(ev, center, sign, False)),
            )
        )
        iv, it = _ellipsoid(
            center + np.array([0, 0, EYE_R * 0.86]), (EYE_R * 0.45, EYE_R * 0.45, EYE_R * 0.22), 20, 12
        )
        parts.append(
            Part(
                "iris_" + ("left" if sign > 0 else "right"),
                iv,
                it,
                IRIS,
                _deltas(_eye_fields(iv, center, sign, True)),
            )
        )
    return FaceModel(
        name="builtin",
        parts=parts,
        pivot=np.array([0.0, -0.9, -0.1]),
        camera_position=(0.0, 0.05, 4.6),
        camera_focus=(0.0, -0.08, 0.0),
        view_angle=30.0,
    )


def weights_from_values(values: np.ndarray, channels: list[str]) -> np.ndarray:
    """(frames, 61) ARKIT61-ordered weights from a take's (frames, channels) values; missing → 0."""
    from capture.channels import canonical, is_known

    out = np.zeros((values.shape[0], len(ARKIT61)), dtype=np.float64)
    for j, name in enumerate(channels):
        if is_known(name):
            out[:, _IDX[canonical(name)]] = values[:, j]
    return out


__all__ = ["FaceModel", "Part", "builtin_face", "vertex_normals", "weights_from_values"]
