"""A walker from the user's own MJCF file (e.g. a rodent model exported from a lab's pipeline)."""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

from dm_control import mjcf

from vnl.errors import VnlError
from vnl.walkers.base import Walker, add_tracking_cameras, collide_with_arena_only


def build(xml_path: str, root_body: str, self_collision: bool = False) -> Walker:
    """Loads `xml_path` with PyMJCF as a walker rooted at body `root_body`.

    The file's world-level geoms (its own floor, if any) are dropped, and a free joint on the
    root body is removed: the arena gives the walker its free joint. Side and back tracking
    cameras are added to the root body. Errors name the file and what is wrong with it.
    """
    path = Path(xml_path).expanduser()
    if not path.is_file():
        raise VnlError(f"walker_xml: no such file {str(path)!r}")
    try:
        model = mjcf.from_path(str(path))
    except Exception as e:  # PyMJCF raises ValueError, KeyError, lxml errors ... for a bad file
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise VnlError(f"walker_xml: could not parse {str(path)!r} as MJCF: {first}") from None
    root = model.find("body", root_body)
    if root is None:
        bodies = [b.name for b in model.find_all("body") if b.name]
        raise VnlError(
            f"walker_xml: {str(path)!r} has no body named {root_body!r} (set root_body); "
            f"its bodies are: {', '.join(bodies) or '(none named)'}"
        )
    model.model = "walker"  # names become walker/<name>, as for the built-in walkers
    for geom in list(model.worldbody.geom):
        geom.remove()  # the file's own floor; the arena provides the ground
    free_joints = [root.freejoint] if root.freejoint is not None else []
    for joint in free_joints + [j for j in root.joint if j.type == "free"]:
        joint.remove()
    if not self_collision:
        collide_with_arena_only(model)
    try:
        add_tracking_cameras(root, distance=1.5, height=0.75)
    except ValueError:
        pass  # the file already has cameras named side/back
    name = Path(path).stem
    return Walker(name=name, mjcf_model=model, root_body=root_body)


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes (hex), cached while its size and modification time stay."""
    st = Path(path).stat()
    return _sha256(str(Path(path).absolute()), st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=32)
def _sha256(path: str, size: int, mtime_ns: int) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
