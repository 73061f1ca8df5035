"""Hostile camera-model files (issue 31, items 4, 5 and 8): every reader refuses a malformed, oversized or
out-of-range file with a ModelFileError naming the file and the field (exit 2), never a traceback (exit 70) or a
silent acceptance. Part 1: each failure the tester found, as its own case. Part 2: a seeded fuzz of files mutated
from good ones in every format, run through `convert`, `diff` and `detect --model` in process."""

from __future__ import annotations

import json
import random
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from circcal.cli import main
from circcal.errors import InputError, ModelFileError
from circcal.formats import read_model, write_camera
from circcal.formats.limits import MAX_FOCAL_PX, MAX_MODEL_FILE_BYTES, MAX_NESTING_DEPTH
from circcal.model import Camera

CAM = Camera(640, 480, 550.0, 552.0, 320.5, 240.25, [-0.1, 0.05, 0.001, -0.001, 0.01])
CAMERAS = {
    "opencv5": CAM,
    "rational": Camera(
        640, 480, 550.0, 552.0, 320.5, 240.25, [-0.1, 0.05, 0.001, -0.001, 0.01, 0.2, 0.01, 0.002], "rational"
    ),
    "thin-prism": Camera(
        640,
        480,
        550.0,
        552.0,
        320.5,
        240.25,
        [-0.1, 0.05, 0.001, -0.001, 0.01, 0.2, 0.01, 0.002, 1e-3, 2e-4, -1e-3, 3e-4],
        "thin-prism",
    ),
    "fisheye": Camera(640, 480, 300.0, 301.0, 320.5, 240.25, [0.01, -0.002, 0.001, -0.0001], "fisheye"),
}
#: file name per format; the lens models each holds
FORMATS = {
    "model.json": ("opencv5", "rational", "thin-prism", "fisheye"),
    "cam.yaml": ("opencv5", "rational", "thin-prism", "fisheye"),
    "cam.xml": ("opencv5", "rational", "thin-prism", "fisheye"),
    "cam.cameramodel": ("opencv5", "rational", "thin-prism"),
    "cameras.txt": ("opencv5", "rational", "fisheye"),
    "left_camera_info.yaml": ("opencv5", "rational", "fisheye"),
}

MODEL_JSON = {
    "width": 640,
    "height": 480,
    "fx": 500.0,
    "fy": 500.0,
    "cx": 320.0,
    "cy": 240.0,
    "dist": [0.0, 0.0, 0.0, 0.0, 0.0],
}


def _good(tmp_path: Path, name: str, lens: str = "opencv5") -> str:
    p = tmp_path / f"good_{lens}_{name}"
    write_camera(p, CAMERAS[lens])
    return p.read_text()


def _same(a: Camera, b: Camera) -> bool:
    return (a.width, a.height, a.lens) == (b.width, b.height, b.lens) and np.allclose(
        a.intrinsics, b.intrinsics, rtol=1e-9, atol=0
    )


def _refused(path: Path, *fields: str) -> str:
    """read_model refuses ``path`` with one line naming it and each of ``fields``."""
    with pytest.raises(ModelFileError) as exc:
        read_model(path)
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg, msg
    for f in fields:
        assert f.lower() in msg.lower(), msg
    return msg


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


# --- part 1: each failure found -------------------------------------------------------------------------------------


def _opencv(tmp_path: Path, old: str, new: str, xml: bool = False, count: int = 1) -> Path:
    text = _good(tmp_path, "c.xml" if xml else "c.yaml")
    assert old in text, text
    return _write(tmp_path, "bad.xml" if xml else "bad.yaml", text.replace(old, new, count))


@pytest.mark.parametrize(
    "old,new,fields",
    [
        ("rows: 3", "rows: 2", ("camera_matrix", "rows")),  # rows x cols against the data
        ("cols: 5", "cols: 4", ("distortion_coefficients", "cols")),
        ("dt: d", "dt: zz", ("camera_matrix", "dt")),  # dt not a type
        ("image_width: 640", "image_width: abc", ("image_width", "'abc'")),  # was read as 1.797e308
        ("image_height: 480", "image_height: 1e300", ("image_height",)),
        ("image_width: 640", "image_width: " + "9" * 400, ("image_width",)),
    ],
)
def test_opencv_yaml_values(tmp_path, old, new, fields):
    _refused(_opencv(tmp_path, old, new), *fields)


def test_opencv_matrix_as_string_sequence_or_two_rows(tmp_path):
    text = _good(tmp_path, "c.yaml")
    head, tail = text.split("camera_matrix:", 1)
    rest = tail[tail.index("distortion_coefficients") :]
    for i, node in enumerate(
        (
            "hello",
            "[550., 0., 320.5, 0., 552., 240.25, 0., 0., 1.]",
            "!!opencv-matrix\n   rows: 2\n   cols: 3\n   dt: d\n   data: [ 550., 0., 320.5, 0., 552., 240.25 ]",
        )
    ):
        p = _write(tmp_path, f"m{i}.yaml", f"{head}camera_matrix: {node}\n{rest}")
        _refused(p, "camera_matrix")


def test_opencv_third_row_of_K(tmp_path):
    text = _good(tmp_path, "c.yaml")
    new = re.sub(r"0\., 0\., 1\. \]", "0.5, 0., 2. ]", text, count=1)
    assert new != text
    _refused(_write(tmp_path, "k.yaml", new), "third row", "0.5")


def test_opencv_xml_entity_and_nan(tmp_path):
    text = _good(tmp_path, "c.xml")
    ent = text.replace('<?xml version="1.0"?>', '<?xml version="1.0"?>\n<!DOCTYPE x [<!ENTITY big "550.">]>')
    _refused(_write(tmp_path, "e.xml", ent), "DOCTYPE")
    nan = re.sub(r"5\.5000000000000000e\+02|550\.", "nan", text, count=1)
    assert nan != text
    _refused(_write(tmp_path, "n.xml", nan), "camera_matrix", "finite")


@pytest.mark.parametrize(
    "name,text",
    [
        ("deep.json", '{"camera": ' + "[" * 100_000 + "]" * 100_000 + "}"),
        ("deep2.json", "[" * 5000 + "]" * 5000),
        ("deep_camera_info.yaml", "K: " + "[" * 100_000 + "]" * 100_000 + "\n"),
        ("deep.yaml", "%YAML:1.0\n---\ncamera_matrix: " + "[" * 100_000 + "]" * 100_000 + "\n"),
        ("dash.yaml", "%YAML:1.0\n---\ncamera_matrix: " + "- " * 100_000 + "1\n"),
        (
            "deep.xml",
            '<?xml version="1.0"?>\n<opencv_storage>' + "<a>" * 100_000 + "</a>" * 100_000 + "</opencv_storage>",
        ),
        ("deep.cameramodel", "{'lensmodel': " + "[" * 150 + "]" * 150 + "}"),
    ],
)
def test_deep_nesting(tmp_path, name, text):
    _refused(_write(tmp_path, name, text), "nested")


def test_yaml_aliases_refused(tmp_path):
    laughs = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{c}: &{c} [{', '.join([f'*{p}'] * 9)}]\n" for p, c in zip("abcdefgh", "bcdefghi")
    )
    _refused(_write(tmp_path, "lol_camera_info.yaml", laughs), "alias")


@pytest.mark.parametrize("digits", [400, 5000])
def test_huge_integers_every_format(tmp_path, digits):
    n = "7" * digits
    cases = {
        "i.json": json.dumps({**MODEL_JSON, "width": 0}).replace('"width": 0', f'"width": {n}'),
        "i_camera_info.yaml": _good(tmp_path, "c_camera_info.yaml").replace("image_width: 640", f"image_width: {n}"),
        "i.yaml": _good(tmp_path, "c.yaml").replace("image_width: 640", f"image_width: {n}"),
        "i.xml": _good(tmp_path, "c.xml").replace("<image_width>640<", f"<image_width>{n}<"),
        "i.cameramodel": _good(tmp_path, "c.cameramodel").replace("[ 640, 480 ]", f"[ {n}, 480 ]"),
        "cameras.txt": _good(tmp_path, "cameras.txt").replace(" 640 480 ", f" {n} 480 "),
    }
    for name, text in cases.items():
        assert n in text, name
        _refused(_write(tmp_path, name, text))


@pytest.mark.parametrize(
    "expr,what",
    [
        ("-(1)", "intrinsics"),
        ("1+2", "Add"),
        ("2**10000", "Pow"),
        ("__import__('os')", "Call"),
        ("1 if 1 else 2", "IfExp"),
        ("[1 for x in ()]", "ListComp"),
    ],
)
def test_cameramodel_operators_refused(tmp_path, expr, what):
    text = _good(tmp_path, "c.cameramodel").replace("'intrinsics': [ ", f"'intrinsics': [ {expr}, ", 1)
    _refused(_write(tmp_path, "op.cameramodel", text), what)


def test_cameramodel_negative_literals_still_read(tmp_path):
    p = tmp_path / "neg.cameramodel"
    write_camera(p, CAM)
    assert "-0.1" in p.read_text()
    assert _same(read_model(p)[0], CAM)


def test_booleans_are_no_numbers(tmp_path):
    _refused(
        _write(
            tmp_path,
            "b_camera_info.yaml",
            _good(tmp_path, "c_camera_info.yaml").replace("image_width: 640", "image_width: true"),
        ),
        "image_width",
        "True",
    )
    _refused(
        _write(tmp_path, "b.cameramodel", _good(tmp_path, "c.cameramodel").replace("[ 640, 480 ]", "[ True, 480 ]")),
        "imagersize",
    )
    _refused(_write(tmp_path, "b.json", json.dumps({**MODEL_JSON, "fx": True})), "fx")


@pytest.mark.parametrize(
    "field,value,needle",
    [
        ("width", 1e300, "width"),
        ("height", 2**20 + 1, "height"),
        ("width", 640.5, "width"),
        ("width", 0, "width"),
        ("fx", 1e-300, "fx"),
        ("fy", 1e308, "fy"),
        ("fx", MAX_FOCAL_PX * 2, "fx"),
        ("fx", -500.0, "fx"),
        ("cx", 1e9, "cx"),
        ("dist", [1e5, 0, 0, 0, 0], "k1"),
        ("dist", [0, 0, 0, 0, "x"], "dist"),
    ],
)
def test_value_bounds(tmp_path, field, value, needle):
    _refused(_write(tmp_path, "v.json", json.dumps({"camera": {**MODEL_JSON, field: value}})), needle)


def test_value_bounds_in_foreign_formats(tmp_path):
    _refused(_write(tmp_path, "cameras.txt", "1 PINHOLE 640 480 1e-300 500 320 240\n"), "fx")
    _refused(
        _write(
            tmp_path, "f_camera_info.yaml", _good(tmp_path, "c_camera_info.yaml").replace("[550.0,", "[1.0e+308,", 1)
        ),
        "fx",
    )
    _refused(_write(tmp_path, "k.cameramodel", _good(tmp_path, "c.cameramodel").replace("-0.1,", "-1e9,", 1)), "k1")


def test_duplicate_keys(tmp_path):
    text = (
        '{"camera": {"width": 640, "height": 480, "fx": 500,\n "fx": 600, "fy": 500, "cx": 320, "cy": 240, '
        '"dist": [0, 0, 0, 0, 0]}}'
    )
    _refused(_write(tmp_path, "d.json", text), "duplicate key 'fx' at line 2")
    ros = _good(tmp_path, "c_camera_info.yaml")
    _refused(_write(tmp_path, "d_camera_info.yaml", ros + "image_width: 640\n"), "duplicate key 'image_width'")
    yml = _good(tmp_path, "c.yaml")
    _refused(_write(tmp_path, "d.yaml", yml + "image_width: 640\n"), "duplicate key 'image_width'")
    _refused(
        _write(tmp_path, "e.yaml", yml.replace("cols: 3", "cols: 3\n   cols: 3", 1)),
        "duplicate key 'cols'",
        "camera_matrix",
    )
    mr = _good(tmp_path, "c.cameramodel").replace("'imagersize'", "'lensmodel': 'LENSMODEL_OPENCV5',\n'imagersize'")
    _refused(_write(tmp_path, "d.cameramodel", mr), "duplicate key 'lensmodel'")


def test_unknown_fields_in_model_json_refused_foreign_extras_ignored(tmp_path):
    _refused(_write(tmp_path, "s.json", json.dumps({"camera": {**MODEL_JSON, "skew": 0.5}})), "skew")
    _refused(_write(tmp_path, "t.json", json.dumps({"camera": MODEL_JSON, "extra_section": {}})), "extra_section")
    _refused(_write(tmp_path, "f.json", json.dumps({"camera": MODEL_JSON, "format": "other"})), "format")
    # a foreign format's extra fields are its custom: ignored
    ros = _good(tmp_path, "c_camera_info.yaml") + "vendor_note: hello\n"
    assert _same(read_model(_write(tmp_path, "x_camera_info.yaml", ros))[0], CAM)
    yml = _good(tmp_path, "c.yaml") + "avg_reprojection_error: 0.2\n"
    assert _same(read_model(_write(tmp_path, "x.yaml", yml))[0], CAM)


def test_file_size_refused_before_reading(tmp_path, monkeypatch):
    import circcal.formats as formats

    p = _write(tmp_path, "big.json", " " * 2000 + json.dumps(MODEL_JSON))
    monkeypatch.setattr(formats, "MAX_MODEL_FILE_BYTES", 1000)
    msg = _refused(p, "bytes")
    assert "1000" in msg
    assert MAX_MODEL_FILE_BYTES == 64 * 2**20


def test_diff_refuses_fixed_huge_focal_and_keeps_no_output(tmp_path, capsys):
    good = tmp_path / "good.json"
    write_camera(good, CAM)
    cases = {
        "fixed.json": {"camera": CAM.to_dict(), "fixed": 5},
        "fixed2.json": {"camera": CAM.to_dict(), "fixed": ["k3", "skew"]},
        "views.json": {"camera": CAM.to_dict(), "views": 7},
        "f308.json": {"camera": {**CAM.to_dict(), "fx": 1e308}},
    }
    for name, doc in cases.items():
        p = _write(tmp_path, name, json.dumps(doc))
        out = tmp_path / f"{name}.out.json"
        assert main(["diff", str(p), str(good), "--json", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and name in err, err
        assert not out.exists()


def test_cameramodel_optimisation_inputs_checked(tmp_path, capsys):
    import base64
    import io

    def model(inputs: dict | None, blob: bytes | None = None) -> str:
        if blob is None:
            buf = io.BytesIO()
            np.savez_compressed(buf, **inputs)
            blob = base64.b85encode(buf.getvalue())
        return (
            _good(tmp_path, "c.cameramodel").rstrip().rstrip("}")
            + f"    'icam_intrinsics': 0,\n    'optimization_inputs': {blob!r},\n}}\n"
        )

    good = tmp_path / "good.cameramodel"
    write_camera(good, CAM)
    for name, text, needle in (
        (
            "lack.cameramodel",
            model({"intrinsics": np.zeros((1, 9)), "lensmodel": "LENSMODEL_OPENCV5"}),
            "observations_board",
        ),
        ("blob.cameramodel", model(None, b"not b85 at all ~~~"), "optimization_inputs"),
        ("str.cameramodel", model(None, b"x").replace("b'x'", "'text'"), "optimization_inputs"),
    ):
        p = _write(tmp_path, name, text)
        out = tmp_path / "o.json"
        assert main(["diff", str(p), str(good), "--json", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and name in err and needle in err, err
        assert not out.exists()


def test_circcals_own_files_read_back(tmp_path):
    for name, lenses in FORMATS.items():
        for lens in lenses:
            p = tmp_path / f"{lens}_{name}"
            write_camera(p, CAMERAS[lens])
            cam = read_model(p)[0]
            assert cam.lens == CAMERAS[lens].lens or name == "cameras.txt"
            assert np.allclose(cam.intrinsics, CAMERAS[lens].intrinsics, rtol=1e-9, atol=1e-9), (name, lens)


# --- part 2: mutated files through the commands ------------------------------------------------------------------

_NUMBER = re.compile(r"(?<![\w.])-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")
_HOSTILE_VALUES = [
    "9" * 400,
    "1e309",
    "nan",
    ".nan",
    "NaN",
    "-550.0",
    "0",
    "true",
    "True",
    "'x'",
    '"x"',
    "1e-300",
    "-1e6",
    "[1, 2]",
    "{}",
    "null",
    "None",
    "2**64",
    "-(1)",
    "1e+308",
    "4294967936",
    "&a 1",
    "*a",
]


def _mutate(text: str, rng: random.Random, fname: str) -> str:
    """One seeded mutation of a good file's text."""
    lines = text.splitlines(keepends=True)
    op = rng.randrange(11)
    if op == 0:  # truncate
        return text[: rng.randrange(1, max(2, len(text) - 1))]
    if op == 1 and len(lines) > 1:  # delete a line
        del lines[rng.randrange(len(lines))]
        return "".join(lines)
    if op == 2 and len(lines) > 1:  # duplicate a line
        i = rng.randrange(len(lines))
        lines.insert(i, lines[i])
        return "".join(lines)
    if op == 3 and len(lines) > 2:  # swap two lines
        i, j = rng.sample(range(len(lines)), 2)
        lines[i], lines[j] = lines[j], lines[i]
        return "".join(lines)
    if op == 4:  # nest deeply
        i = rng.randrange(len(text))
        depth = rng.choice([MAX_NESTING_DEPTH + 1, 500, 50_000])
        return text[:i] + "[" * depth + "]" * depth + text[i:]
    if op == 5:  # aliases / anchors / entities
        return rng.choice(["a: &x [1, 2]\nb: *x\n", '<!DOCTYPE x [<!ENTITY e "1">]>\n', "&x "]) + text
    if op == 6:  # unknown field
        if fname.endswith(".json"):
            d = json.loads(text)
            d[rng.choice(["skew", "extra"])] = 0.5
            if rng.random() < 0.5:
                d["camera"]["skew"] = 0.5
            return json.dumps(d)
        return text + rng.choice(["\nskew: 0.5\n", "\n# a comment\n", "\n2 PINHOLE 640 480 500 500 320 240\n"])
    if op == 7:  # change a matrix size (rows, cols, number of values)
        m = re.search(r"(rows|cols)[:\">]+\s*(\d+)", text)
        if m:
            return text[: m.start(2)] + str(rng.choice([0, 1, 2, 4, 99999])) + text[m.end(2) :]
        return re.sub(r"(\d+\.\d+)([,\] ])", r"\1, \1\2", text, count=1)
    # 8-10: replace a number with a hostile value
    nums = list(_NUMBER.finditer(text))
    if not nums:
        return text[: len(text) // 2]
    m = rng.choice(nums)
    return text[: m.start()] + rng.choice(_HOSTILE_VALUES) + text[m.end() :]


def _png(tmp_path: Path) -> Path:
    img = np.full((48, 64), 200, np.uint8)
    cv2.circle(img, (20, 20), 6, 30, -1)
    p = tmp_path / "img.png"
    assert cv2.imwrite(str(p), img)
    return p


def _one_line(err: str, path: Path) -> None:
    err = err.strip()
    assert "Traceback" not in err and "internal error" not in err, err
    assert len(err.splitlines()) == 1, err
    assert path.name in err, err


def test_fuzz_mutated_model_files(tmp_path, capsys):
    rng = random.Random(20261205)
    img = _png(tmp_path)
    goods = []
    for name, lenses in FORMATS.items():
        for lens in lenses:
            p = tmp_path / "good" / f"{lens}_{name}"
            p.parent.mkdir(exist_ok=True)
            write_camera(p, CAMERAS[lens])
            goods.append((name, p))
    reference = tmp_path / "good" / "reference.json"
    write_camera(reference, CAM)
    n_files, n_valid = 0, 0
    for k in range(168):
        name, good = goods[k % len(goods)]
        text = good.read_text()
        bad = _mutate(text, rng, name)
        if rng.random() < 0.15:
            bad = _mutate(bad, rng, name)
        if bad == text:
            continue
        case = tmp_path / f"case{k:03d}"
        case.mkdir()
        f = case / f"m{k:03d}_{name}"
        f.write_text(bad)
        n_files += 1
        try:
            read_model(f)
            valid = True
        except InputError:
            valid = False
        outs = {"convert": case / "out.json", "diff": case / "diff.json", "detect": case / "det.json"}
        runs = {
            "convert": ["convert", str(f), str(outs["convert"])],
            "diff": ["diff", str(f), str(reference), "--json", str(outs["diff"])],
            "detect": [
                "detect",
                str(img),
                "--grid",
                "7x7",
                "--model",
                str(f),
                "--json",
                str(outs["detect"]),
                "--quiet",
            ],
        }
        for cmd, argv in runs.items():
            rc = main(argv)
            captured = capsys.readouterr()
            if not valid:
                assert rc == 2, (cmd, f.name, rc, captured.err[-2000:])
                _one_line(captured.err, f)
                assert not outs[cmd].exists(), (cmd, f.name)
            else:
                assert rc in (0, 1, 2), (cmd, f.name, rc, captured.err[-2000:])
                assert "Traceback" not in captured.err, captured.err
                if cmd == "convert":
                    assert rc == 0, captured.err
                    assert np.allclose(read_model(outs[cmd])[0].intrinsics, read_model(f)[0].intrinsics)
                elif cmd == "diff" and rc == 0:
                    assert "rms_px" in json.loads(outs[cmd].read_text()) or outs[cmd].exists()
        n_valid += valid
    assert n_files >= 150
    assert n_valid < 0.4 * n_files, (n_valid, n_files)  # most mutations are refused


@pytest.mark.parametrize("name", ["m.yaml", "m.json", "m.cameramodel", "cameras.txt", "m.xml"])
def test_an_empty_file_is_said_to_be_empty(tmp_path, name):
    # OpenCV's FileStorage answered an empty .yaml with its own assertion text ("(-215:Assertion failed) buf")
    (tmp_path / name).write_text(" \n")
    with pytest.raises(ModelFileError, match=f"camera file {tmp_path / name}: an empty file$"):
        read_model(tmp_path / name)
