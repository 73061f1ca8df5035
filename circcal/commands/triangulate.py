"""``circcal triangulate --rig rig.json --points left=l.csv --points right=r.csv [--out points.csv]``: 3-D points of
pixels seen by two or more cameras of a calibrated rig, each with its uncertainty (:func:`circcal.rig.triangulate`).

Pixel files (one per camera, one row per point, the same points in the same order in every file):

* CSV: ``u,v`` per row, or ``id,u,v`` (the ids, when given, must agree between the files); a first row that is not
  numbers is a header; ``#`` starts a comment; an empty field or ``nan`` marks a point the camera does not see.
* JSON: a list of ``[u, v]`` (``null`` for an unseen point), or ``{"points": [...]}`` with such a list.

Pixels follow OpenCV's convention (integer coordinates are pixel centres). Points come out in the rig frame (the
reference camera's, mm) with their 1-sigma along x, y, z and along the worst direction (the largest eigenvalue's
root of the 3x3 covariance: pixel noise plus, when the rig holds one, the calibration's covariance; mrcal's
definition).
"""

from __future__ import annotations

import argparse
import csv
import math
from collections.abc import Callable
from pathlib import Path

from circcal.commands.args import positive_float
from circcal.commands.rig import CAMERA_NAME
from circcal.errors import InputError
from circcal.pathnames import display_name

#: The largest pixel file read, bytes.
MAX_POINTS_FILE_BYTES = 64 << 20
#: --out by extension.
OUT_FORMATS = {".csv": "csv", ".json": "json"}


#: The largest |u|, |v| of a pixel read: 1e7 px is ten image sides of the largest image a camera file may describe
#: (beyond, a value is a damaged file: 1e308 overflowed in the projection's arithmetic).
MAX_PIXEL = 1e7
#: With --out, the console shows this many points' rows (the file holds them all).
CONSOLE_ROWS = 20
#: The points' own noise (their reprojection residuals pooled over their degrees of freedom, 2 per camera less 3
#: per point) beyond this many times the pixel sigma assumed is warned of: their stated sigmas are too small by that
#: factor. One two-camera point (1 degree of freedom) under the assumed noise exceeds 3x with probability 0.27%
#: (chi-square, 1 dof, beyond 9), and the pooled estimate of more points or cameras far less often; the calibration's
#: own error adds to the residuals well below that.
NOISE_FACTOR = 3.0


def _points_arg(text: str) -> tuple[str, Path]:
    """``NAME=FILE`` -> (name, path) (an argparse type)."""
    name, eq, path = str(text).partition("=")
    if not eq or not path or not CAMERA_NAME.fullmatch(name):
        raise argparse.ArgumentTypeError(f"expected NAME=FILE (a camera of the rig and its pixel file), got {text!r}")
    return name, Path(path)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal triangulate`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = sub.add_parser(
        "triangulate",
        help="3-D points of pixels seen by cameras of a calibrated rig, with their uncertainty",
        description="Triangulate pixels of two or more cameras of a rig (circcal's rig.json from calibrate-rig, or "
        "OpenCV's stereo YAML): each point in the reference camera's frame, mm, with its 1-sigma along x, y, z and "
        "the largest, from the pixel noise and the calibration's covariance (mrcal's definition). Pixel files: "
        "CSV rows 'u,v' or 'id,u,v' (a header row allowed; an empty field or nan: not seen), or JSON [[u, v], "
        "...] (null: not seen); one row per point, the same points in the same order in every file.",
    )
    p.add_argument("--rig", type=Path, required=True, help="rig.json (calibrate-rig) or OpenCV's stereo .yaml/.yml")
    p.add_argument(
        "--points",
        action="append",
        type=_points_arg,
        required=True,
        metavar="NAME=FILE",
        help="a camera of the rig and its pixels (CSV or JSON, see above); at least two",
    )
    p.add_argument(
        "--pixel-sigma",
        type=positive_float,
        default=None,
        help="pixel noise, px per coordinate (default: the rig's own, its RMS per point / sqrt(2))",
    )
    p.add_argument(
        "--no-calibration-uncertainty",
        action="store_true",
        help="leave the calibration's covariance out (only the pixel noise)",
    )
    p.add_argument("--out", type=Path, default=None, help="write the points to points.csv or points.json")
    p.set_defaults(func=run)


def read_rig(path: Path):
    """The rig in ``path``: circcal's rig JSON or OpenCV's stereo YAML (by extension).

    Parameters
    ----------
    path : Path

    Returns
    -------
    circcal.rig.RigModel

    Raises
    ------
    InputError
        Naming the file: missing, unreadable, not a rig, or of an unknown extension.
    """
    from circcal.formats.limits import MAX_MODEL_FILE_BYTES
    from circcal.jsonio import read_json
    from circcal.rig import RigModel, read_opencv_stereo

    suffix = path.suffix.lower()
    if suffix == ".json":
        doc = read_json(path, "--rig", max_bytes=MAX_MODEL_FILE_BYTES)
        try:
            return RigModel.from_dict(doc)
        except InputError as exc:
            raise InputError(f"--rig {display_name(path)}: {exc}") from None
    if suffix in (".yaml", ".yml", ".xml"):
        return read_opencv_stereo(path)
    raise InputError(
        f"--rig {display_name(path)}: unknown extension {path.suffix!r}; give circcal's rig.json or OpenCV's stereo "
        f".yaml"
    )


def _is_header(row: list[str]) -> bool:
    """Whether a CSV row's last two fields hold a word (a header such as ``id,u,v``), not numbers."""

    def word(c: str) -> bool:
        try:
            float(c)
        except ValueError:
            return bool(c.strip())
        return False

    return any(word(c) for c in row[-2:])


def _number(text: str, where: str) -> float:
    t = text.strip()
    if t == "" or t.lower() == "nan":
        return math.nan
    try:
        value = float(t)
    except ValueError:
        raise InputError(f"{where}: not a number: {text!r}") from None
    if not abs(value) <= MAX_PIXEL:
        raise InputError(
            f"{where}: a pixel within {MAX_PIXEL:g} px of the origin (nan or empty for an unseen point), got {text!r}"
        )
    return value


def read_points(path: Path, option: str = "--points") -> tuple[list[str] | None, list[tuple[float, float]]]:
    """A pixel file: CSV or JSON (see the module).

    Parameters
    ----------
    path : Path
    option : str
        Names the file in messages.

    Returns
    -------
    ids : list of str or None
        The CSV's first column when it has three.
    pixels : list of (float, float)
        px; NaN for a point not seen.

    Raises
    ------
    InputError
        Naming the file and the row: unreadable, not CSV or JSON of pixels, a row of another width, a value that is
        not a number.
    """
    from circcal.jsonio import parse_json, read_text

    text = read_text(path, option, max_bytes=MAX_POINTS_FILE_BYTES)
    where = f"{option} {display_name(path)}"
    if path.suffix.lower() == ".json" or text.lstrip()[:1] in ("[", "{"):
        try:
            doc = parse_json(text)
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None
        rows = doc.get("points") if isinstance(doc, dict) else doc
        if not isinstance(rows, list):
            raise InputError(f'{where}: expected a list of [u, v] (or {{"points": [...]}})')
        out = []
        for k, r in enumerate(rows):
            if r is None:
                out.append((math.nan, math.nan))
                continue
            ok = isinstance(r, list) and len(r) == 2
            ok = ok and all(v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)) for v in r)
            if not ok:
                raise InputError(f"{where}: point {k} must be [u, v] (numbers, null for unseen), got {r!r}")
            u, v = (math.nan if x is None else float(x) for x in r)
            if not (abs(u) <= MAX_PIXEL or math.isnan(u)) or not (abs(v) <= MAX_PIXEL or math.isnan(v)):
                raise InputError(f"{where}: point {k} must be a pixel within {MAX_PIXEL:g} px of the origin")
            out.append((u, v))
        _both_or_neither(out, lambda k: f"{where}: point {k}")
        return None, out
    rows = [
        (n, r)
        for n, r in enumerate(csv.reader(text.splitlines()), start=1)
        if r and not r[0].lstrip().startswith("#") and any(c.strip() for c in r)
    ]
    if rows and _is_header(rows[0][1]):
        rows = rows[1:]
    for n, r in rows:
        if len(r) != len(rows[0][1]) or len(r) not in (2, 3):
            raise InputError(
                f"{where}: line {n}: expected u,v or id,u,v on every row (as the first), got {len(r)} fields"
            )
    ids = [r[0].strip() for _, r in rows] if rows and len(rows[0][1]) == 3 else None
    if ids is not None:
        first: dict[str, int] = {}
        for (n, _), i in zip(rows, ids):
            if i in first:
                raise InputError(
                    f"{where}: line {n}: point id {display_name(i)!r} given twice (first on line {first[i]})"
                )
            first[i] = n
    pixels = [(_number(r[-2], f"{where}: line {n}"), _number(r[-1], f"{where}: line {n}")) for n, r in rows]
    _both_or_neither(pixels, lambda k: f"{where}: line {rows[k][0]}")
    return ids, pixels


def _both_or_neither(pixels: list[tuple[float, float]], where: Callable[[int], str]) -> None:
    """Refuse a point with one coordinate only (``where(k)`` names point k): an unseen point has neither."""
    for k, (u, v) in enumerate(pixels):
        if math.isnan(u) != math.isnan(v):
            raise InputError(f"{where(k)}: one coordinate only: give u and v, or neither (an unseen point)")


def run(args: argparse.Namespace) -> int:
    """Triangulate the pixel files of the arguments through the rig and print (and write) the points.

    Parameters
    ----------
    args : argparse.Namespace
        The arguments :func:`add_parser`'s parser parsed.

    Returns
    -------
    int
        The exit status: 0.

    Raises
    ------
    InputError
        A bad argument or input file (the CLI prints it and exits 2).
    """
    import sys

    import numpy as np

    from circcal.outputs import Outputs
    from circcal.rig import triangulate

    fmt = None
    if args.out is not None:
        fmt = OUT_FORMATS.get(args.out.suffix.lower())
        if fmt is None:
            raise InputError(f"--out {display_name(args.out)}: unknown extension; give points.csv or points.json")
    rig = read_rig(args.rig)
    names = [n for n, _ in args.points]
    for name in names:
        if name not in rig.names:
            raise InputError(f"--points {name}=...: no camera {name!r} in the rig (cameras: {', '.join(rig.names)})")
    if len(set(names)) != len(names):
        twice = next(n for n in names if names.count(n) > 1)
        raise InputError(f"--points {twice}: camera {twice!r} given twice")
    if len(names) < 2:
        raise InputError(f"--points: triangulation needs the pixels of at least two cameras, got {len(names)}")
    if args.pixel_sigma is None and rig.rms_px is None:
        raise InputError(f"--rig {display_name(args.rig)} states no pixel noise (no rms_px): give --pixel-sigma PX")
    read = {name: read_points(path) for name, path in args.points}
    counts = {name: len(p) for name, (_, p) in read.items()}
    if len(set(counts.values())) > 1:
        raise InputError(
            "--points: the files hold different numbers of points ("
            + ", ".join(f"{n}: {c}" for n, c in counts.items())
            + "); give one row per point in every file"
        )
    if not any(counts.values()):
        raise InputError(f"--points: the files hold no points ({', '.join(str(p) for _, p in args.points)})")
    ids = next((i for i, _ in read.values() if i is not None), None)
    for name, (i, _) in read.items():
        if i is not None and i != ids:
            raise InputError(
                f"--points {name}: its point ids differ from the other file's; give the points in one order"
            )
    ids = ids or [str(k) for k in range(next(iter(counts.values())))]
    pixels = {name: np.array(p, dtype=np.float64).reshape(-1, 2) for name, (_, p) in read.items()}
    with Outputs(inputs=[args.rig, *(p for _, p in args.points)]) as outputs:
        out = None if args.out is None else outputs.file(args.out, "--out")
        tri = triangulate(
            rig,
            pixels,
            pixel_sigma=args.pixel_sigma,
            calibration=False if args.no_calibration_uncertainty else None,
        )
        rows = _rows(ids, tri)
        noisy = noise_warning(tri, given=args.pixel_sigma is not None)
        if noisy:
            print(f"circcal triangulate: warning: {noisy}", file=sys.stderr)
        print(
            f"{len(ids)} points in the frame of {rig.names[0]} (the reference camera), mm; 1-sigma from pixel noise "
            f"{tri.pixel_sigma:.4g} px per coordinate"
            + (" and the calibration's covariance" if tri.calibration_included else " only (no calibration covariance)")
        )
        print(
            f"{'point':>8} {'x':>11} {'y':>11} {'z':>11} {'sx':>8} {'sy':>8} {'sz':>8} {'largest':>8} {'rms px':>7} cams"
        )
        shown = len(rows) if out is None else min(len(rows), CONSOLE_ROWS)
        for k, r in enumerate(rows[:shown]):
            vals = [
                r[key] for key in ("x_mm", "y_mm", "z_mm", "sigma_x_mm", "sigma_y_mm", "sigma_z_mm", "sigma_largest_mm")
            ]
            if r["x_mm"] is None:
                given = [n for n in tri.cameras if np.isfinite(pixels[n][k]).all()]
                lost = len(given) - r["n_cameras"]
                why = (
                    f"; {lost} of them cannot unproject its pixel (beyond its lens's one-to-one field, or at a pole "
                    f"of its fitted rational lens: see the rig's verdict)"
                    if lost
                    else (
                        "; their rays meet at no finite point in front of them (check which row is which point)"
                        if r["n_cameras"] >= 2
                        else ""
                    )
                )
                print(f"{r['id']:>8} (given by {len(given)} camera(s){why}: no point)")
                continue
            print(
                f"{r['id']:>8} {vals[0]:11.3f} {vals[1]:11.3f} {vals[2]:11.3f} {vals[3]:8.3f} {vals[4]:8.3f} "
                f"{vals[5]:8.3f} {vals[6]:8.3f} {r['rms_px']:7.3f} {r['n_cameras']}"
            )
        if shown < len(rows):
            lost = sum(r["x_mm"] is None for r in rows[shown:])
            print(
                f"... {len(rows) - shown} more point(s) in {display_name(args.out)}"
                + (f" ({lost} of them without a point)" if lost else "")
            )
        flagged = [r for r in rows if r["behind"]]
        if flagged:
            print(
                f"{len(flagged)} point(s) behind a camera that sees them: "
                + "; ".join(f"{r['id']} (behind {r['behind'].replace(';', ', ')})" for r in flagged[:10])
                + ("; ..." if len(flagged) > 10 else "")
                + ": their pixels do not show one point (check which row is which point in each file); their "
                "positions mean nothing"
            )
        if out is not None:
            _write(out, fmt, rows, rig, tri)
            outputs.commit()
            print(f"wrote {display_name(args.out)}")
    return 0


def noise_warning(tri, *, given: bool) -> str:
    """Whether the points reproject far worse than the pixel noise assumed: the line that says so, or ``""``.

    The points' noise per coordinate is estimated from their residuals, ``sqrt(sum(rms_n^2 k_n) / sum(2 k_n - 3))``
    over the points triangulated in front of their ``k_n >= 2`` cameras (``rms_n`` the RMS over its cameras of the
    2-D norm); beyond :data:`NOISE_FACTOR` times ``tri.pixel_sigma`` the stated sigmas are too small.

    Parameters
    ----------
    tri : circcal.rig.triangulate.Triangulated
    given : bool
        Whether the pixel sigma was given (``--pixel-sigma``) or the rig's own.

    Returns
    -------
    str
        One line naming ``--pixel-sigma``, or ``""``.
    """
    import numpy as np

    k = np.asarray(tri.n_views, dtype=np.float64)
    ok = np.isfinite(tri.rms_px) & (k >= 2) & ~np.any(tri.behind, axis=1)
    dof = float(np.sum(2.0 * k[ok] - 3.0))
    if dof <= 0:
        return ""
    noise = float(np.sqrt(np.sum(tri.rms_px[ok] ** 2 * k[ok]) / dof))
    if not noise > NOISE_FACTOR * tri.pixel_sigma:
        return ""
    source = "given (--pixel-sigma)" if given else "assumed (the rig's own: its RMS per point / sqrt(2))"
    return (
        f"these points reproject with {noise:.3g} px of noise per coordinate ({int(ok.sum())} points, {dof:.0f} "
        f"degrees of freedom), {noise / tri.pixel_sigma:.0f}x the {tri.pixel_sigma:.3g} px {source}: the stated "
        f"sigmas are too small; give --pixel-sigma {noise:.2g} (the noise of these pixels)"
    )


def _rows(ids: list[str], tri) -> list[dict]:
    """One dict per point: id, x/y/z mm, their sigmas, the largest sigma, rms_px (None where no point), n_cameras,
    behind (the cameras it lies behind, ';'-separated; "" for none)."""
    import numpy as np

    largest = np.sqrt(np.maximum(np.linalg.eigvalsh(np.nan_to_num(tri.covariance))[:, -1], 0.0))
    std = tri.std_mm  # once: a property over every point (per row it made 200,000 points take minutes)
    rows = []
    for k, i in enumerate(ids):
        ok = bool(np.isfinite(tri.points[k]).all())
        vals = [*tri.points[k], *std[k], largest[k], tri.rms_px[k]]
        r = {"id": i}
        keys = ("x_mm", "y_mm", "z_mm", "sigma_x_mm", "sigma_y_mm", "sigma_z_mm", "sigma_largest_mm", "rms_px")
        r.update({key: (float(v) if ok else None) for key, v in zip(keys, vals)})
        r["n_cameras"] = int(tri.n_views[k])
        r["behind"] = ";".join(n for n, b in zip(tri.cameras, tri.behind[k]) if b)
        rows.append(r)
    return rows


def _write(path: Path, fmt: str, rows: list[dict], rig, tri) -> None:
    """The points as CSV (empty fields where no point) or JSON."""
    import io

    from circcal import atomic
    from circcal.jsonio import dumps

    if fmt == "json":
        doc = {
            "frame": f"camera {rig.names[0]!r} (the rig's reference), mm",
            "pixel_sigma_px": tri.pixel_sigma,
            "calibration_included": tri.calibration_included,
            "cameras": list(tri.cameras),
            "points": rows,
        }
        atomic.write_text(path, dumps(doc, indent=1) + "\n")
        return
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    keys = list(rows[0]) if rows else ["id"]
    w.writerow(keys)
    for r in rows:
        w.writerow(["" if r[k] is None else (repr(r[k]) if isinstance(r[k], float) else r[k]) for k in keys])
    atomic.write_text(path, buf.getvalue())
