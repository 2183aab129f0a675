"""Keypoint-to-body maps: which body of a walker each keypoint sits on, where in that body's frame
(its initial offset), and how a keypoint file's numbers become the walker's world (scale, axes).

A map is a YAML file (the rat's, `vnl/mocap/maps/rodent.yaml`, documents every key); `load_map`
takes a shipped map's name (`rodent`) or a path, so a map for any MJCF walker is a file of yours.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from vnl import typed_config
from vnl.errors import VnlError
from vnl.mocap.keypoints import Keypoints

MAPS = Path(__file__).parent / "maps"
_TOP = {"walker", "scale", "animal_scale", "axes", "offset_regularization", "keypoints"}
_ENTRY = {"body", "offset", "regularization"}
_AXES = {"x": 0, "y": 1, "z": 2}


@dataclasses.dataclass(frozen=True)
class KeypointMap:
    """A map (module docstring).

    Attributes:
      names: K keypoint names. bodies: K body names. offsets: (K, 3) metres, in each body's frame.
      regularization: (K,) pull of each fitted offset back to its initial one.
      walker: the walker it is made for. scale: metres per file unit. animal_scale: the animal's
      size relative to the model's. axes: (3, 3) matrix taking a file's xyz to the world's.
    """

    names: tuple[str, ...]
    bodies: tuple[str, ...]
    offsets: np.ndarray
    regularization: np.ndarray
    walker: str = ""
    scale: float = 1.0
    animal_scale: float = 1.0
    axes: np.ndarray = dataclasses.field(default_factory=lambda: np.eye(3))
    source: str = ""

    def apply(self, keypoints: Keypoints) -> Keypoints:
        """`keypoints` (metres, the file's axes) as the walker sees them: only the map's keypoints,
        in its order, turned to the world's axes and divided by `animal_scale`."""
        missing = [n for n in self.names if n not in keypoints.names]
        if missing:
            raise VnlError(
                f"map {self.source}: keypoints {missing} are not in {keypoints.source or 'the data'} "
                f"(it has {list(keypoints.names)}); fix the names in the map"
            )
        sub = keypoints.subset(self.names)
        return dataclasses.replace(sub, positions=sub.positions @ self.axes.T / self.animal_scale)

    def body_ids(self, model) -> np.ndarray:  # noqa: ANN001 - a mujoco.MjModel
        """(K,) body ids in `model` of the map's bodies (`resolve_bodies`)."""
        return resolve_bodies(model, self.bodies, f"map {self.source}")


def resolve_bodies(model, bodies: tuple[str, ...], where: str) -> np.ndarray:  # noqa: ANN001 - a mujoco.MjModel
    """(K,) ids of `bodies` in `model` (a name may omit an attached walker's `walker/` prefix)."""
    import mujoco

    ids, unknown = [], []
    for body in bodies:
        i = next((j for j in (mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, n) for n in
                              (body, f"walker/{body}")) if j >= 0), -1)  # fmt: skip
        (ids if i >= 0 else unknown).append(i if i >= 0 else body)
    if unknown:
        names = [model.body(b).name.removeprefix("walker/") for b in range(1, model.nbody)]
        raise VnlError(f"{where}: bodies {unknown} are not in the walker; its bodies: {', '.join(names)}")
    return np.asarray(ids, np.int32)


def bodies_map(names: tuple[str, ...], walker: str = "") -> KeypointMap:
    """Keypoints that are bodies: each at the origin of the body it is named after (`/` may be
    written `.`, as vnl's NWB export names its PoseEstimationSeries: `walker.torso`), in metres,
    z up, its offset kept (regularization 1e6): `--map bodies`."""
    bodies = tuple(n.replace(".", "/") for n in names)
    k = len(names)
    return KeypointMap(names=tuple(names), bodies=bodies, offsets=np.zeros((k, 3)), regularization=np.full(k, 1e6),
                       walker=walker, source="bodies (each keypoint at the origin of its body)")  # fmt: skip


def load_map(name_or_path: str | Path) -> KeypointMap:
    """A shipped map by name (`rodent`: `vnl/mocap/maps/rodent.yaml`) or a map file."""
    shipped = MAPS / f"{name_or_path}.yaml"
    path = shipped if "/" not in str(name_or_path) and shipped.is_file() else Path(name_or_path)
    if not path.is_file():
        names = sorted(p.stem for p in MAPS.glob("*.yaml"))
        raise VnlError(f"keypoint map not found: {name_or_path} (shipped maps: {', '.join(names)}; or a YAML file)")
    return parse_map(typed_config.load_yaml(str(path), "keypoint map"), str(path))


def parse_map(data: dict, source: str = "") -> KeypointMap:
    """A map from its YAML's values (`load_map`); every problem is a `VnlError` naming `source`."""
    where = f"keypoint map {source}"
    unknown = sorted(set(data) - _TOP)
    if unknown:
        raise VnlError(f"{where}: unknown keys {unknown}; a map has {sorted(_TOP)}")
    entries = data.get("keypoints")
    if not isinstance(entries, dict) or not entries:
        raise VnlError(f"{where}: `keypoints` must map keypoint names to {{body, offset}}")
    default_reg = _number(data.get("offset_regularization", 0.0), f"{where}: offset_regularization", 0.0)
    bodies, offsets, regs = [], [], []
    for name, entry in entries.items():
        if not isinstance(entry, dict) or "body" not in entry or set(entry) - _ENTRY:
            raise VnlError(f"{where}: keypoint {name!r} must be a mapping with body, offset (and regularization)")
        offset = np.asarray(entry.get("offset", [0.0, 0.0, 0.0]), dtype=object)
        if offset.shape != (3,) or not all(isinstance(v, int | float) for v in offset):
            raise VnlError(f"{where}: keypoint {name!r}: offset must be three numbers (metres), got {entry['offset']}")
        bodies.append(str(entry["body"]))
        offsets.append(offset.astype(np.float64))
        regs.append(_number(entry.get("regularization", default_reg), f"{where}: {name}.regularization", 0.0))
    scale = _number(data.get("scale", 1.0), f"{where}: scale", 0.0, strict=True)
    animal = _number(data.get("animal_scale", 1.0), f"{where}: animal_scale", 0.0, strict=True)
    return KeypointMap(
        names=tuple(str(n) for n in entries), bodies=tuple(bodies), offsets=np.stack(offsets),
        regularization=np.asarray(regs), walker=str(data.get("walker", "")), scale=scale, animal_scale=animal,
        axes=_axes(data.get("axes", ["x", "y", "z"]), where), source=source,
    )  # fmt: skip


def _number(value: object, what: str, low: float, strict: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise VnlError(f"{what} must be a number, got {value!r}")
    if value < low or (strict and value == low):
        raise VnlError(f"{what} must be {'>' if strict else '>='} {low:g}, got {value}")
    return float(value)


def _axes(spec: object, where: str) -> np.ndarray:
    """The (3, 3) matrix of `axes: [x, -z, y]` (world x = file x, world y = -file z, world z = file y)."""
    ok = isinstance(spec, list) and len(spec) == 3 and all(isinstance(a, str) for a in spec)
    letters = [a.strip().lstrip("+-") for a in spec] if ok else []
    if not ok or sorted(letters) != ["x", "y", "z"]:
        raise VnlError(
            f"{where}: axes must list x, y and z once each, signed where needed (e.g. [x, -z, y]), got {spec}"
        )
    m = np.zeros((3, 3))
    for row, a in enumerate(spec):
        m[row, _AXES[a.strip().lstrip("+-")]] = -1.0 if a.strip().startswith("-") else 1.0
    return m
