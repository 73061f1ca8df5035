"""File names of any bytes as lossless JSON text (path_to_json / path_from_json) and as one printable line
(display_name); the figures' short labels (name_label). POSIX semantics: a name is bytes."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from circcal.calreport.figures import NAME_CHARS, name_label
from circcal.errors import InputError
from circcal.pathnames import BYTES_PREFIX, display_name, path_from_json, path_to_json

pytestmark = pytest.mark.skipif(os.name != "posix", reason="file names as bytes: POSIX")

#: Characters display_name must never let through: they break a line (str.splitlines), draw nothing, or reorder text.
UNSAFE = set(
    map(
        chr,
        [
            *range(0x20),
            *range(0x7F, 0xA0),
            0x061C,
            0x200E,
            0x200F,
            0x2028,
            0x2029,
            *range(0x202A, 0x202F),
            *range(0x2066, 0x206A),
        ],
    )
)

names_as_bytes = st.one_of(
    st.binary(min_size=1, max_size=40),
    st.binary(max_size=20).map(lambda b: BYTES_PREFIX.encode() + b),  # the prefix itself, then anything
    st.text(min_size=1, max_size=20).map(lambda s: s.encode("utf-8", "surrogatepass")),
).filter(lambda b: b"\x00" not in b)


def _stored(name: str) -> str:
    """What another JSON tool sees after our JSON: the text through a strict UTF-8 round trip."""
    text = json.dumps({"path": path_to_json(name)}, ensure_ascii=False).encode("utf-8")  # strict: no lone surrogates
    return json.loads(text.decode("utf-8"))["path"]


@settings(max_examples=400, deadline=None)
@given(names_as_bytes)
def test_any_bytes_name_survives_json_unchanged(raw):
    name = os.fsdecode(raw)
    stored = _stored(name)
    assert stored == path_to_json(name)
    assert os.fsencode(os.fspath(path_from_json(stored))) == os.fsencode(os.fspath(Path(name)))
    assert os.fsencode(os.fspath(path_from_json(json.loads(json.dumps(stored))))) == os.fsencode(os.fspath(Path(name)))


@settings(max_examples=300, deadline=None)
@given(
    st.text(min_size=1).filter(
        lambda s: "\x00" not in s and not s.startswith(BYTES_PREFIX) and not any(0xD800 <= ord(c) <= 0xDFFF for c in s)
    )
)
def test_a_unicode_name_is_stored_as_is(name):
    assert path_to_json(name) == name
    assert path_from_json(name) == Path(name)


@pytest.mark.parametrize(
    "raw, stored",
    [
        (b"caf\xe9_00.png", "bytes:caf%E9_00.png"),
        (b"100%.png", "100%.png"),  # a UTF-8 name keeps its '%'
        (b"100%\xff.png", "bytes:100%25%FF.png"),  # ... escaped only where the name is stored by bytes
        (b"bytes:x", "bytes:bytes:x"),  # a UTF-8 name that begins with the prefix
        (b"dir/caf\xc3\xa9/x\xe9.png", "bytes:dir/caf\u00e9/x%E9.png"),  # valid UTF-8 stays text
        (b"\xed\xb3\xa9.png", "bytes:%ED%B3%A9.png"),  # an encoded surrogate is not UTF-8
        (b"price$0_$x.png", "price$0_$x.png"),
        ("\U0001f600 a\u200db.png".encode(), "\U0001f600 a\u200db.png"),
    ],
)
def test_stored_forms(raw, stored):
    assert path_to_json(os.fsdecode(raw)) == stored
    assert path_to_json(raw) == stored  # bytes and Path given as well
    assert path_to_json(Path(os.fsdecode(raw))) == stored
    assert os.fsencode(path_from_json(stored)) == os.fsencode(Path(os.fsdecode(raw)))


def test_lone_surrogates_of_older_files_are_read_as_their_bytes():
    assert os.fsencode(path_from_json("caf\udce9_00.png")) == b"caf\xe9_00.png"
    assert path_from_json("bytes:%e9") == Path(os.fsdecode(b"\xe9"))  # lower-case hex read too


@pytest.mark.parametrize(
    "value, words",
    [
        ("bytes:caf%E_00.png", "two hex digits"),
        ("bytes:100%", "two hex digits"),
        ("bytes:%zz", "two hex digits"),
        ("", "empty"),
        ("bytes:", "not a file name"),
        ("a\x00b", "NUL"),
        ("bytes:a%00b", "NUL"),
        ("a\ud800b", "lone surrogate"),
        ("bytes:a\udce9", "lone surrogate"),
        (None, "string"),
        (3, "string"),
        (["a"], "string"),
    ],
)
def test_malformed_stored_names_are_input_errors_naming_the_field(value, words):
    with pytest.raises(InputError, match=words) as exc:
        path_from_json(value, "detections.json: images[3].path")
    msg = str(exc.value)
    assert msg.startswith("detections.json: images[3].path: ") and "\n" not in msg
    msg.encode("utf-8")  # printable: no lone surrogate in the message


@pytest.mark.parametrize("bad", ["", "a\x00b", b"a\x00"])
def test_no_file_system_name_is_empty_or_holds_nul(bad):
    with pytest.raises(ValueError):
        path_to_json(bad)


@pytest.mark.parametrize(
    "name, shown",
    [
        (os.fsdecode(b"caf\xe9_00.png"), "caf\\xe9_00.png"),
        ("new\nline.png", "new\\nline.png"),
        ("a\r\tb", "a\\r\\tb"),
        ("esc\x1b[31mred", "esc\\x1b[31mred"),
        ("del\x7f", "del\\x7f"),
        ("nel\u0085x", "nel\\u0085x"),  # a C1 control (a valid character), not byte 0x85
        (os.fsdecode(b"raw\x85x"), "raw\\x85x"),  # byte 0x85 that is not UTF-8
        ("\u202egnp.exe", "\\u202egnp.exe"),
        ("a\u2066b\u2069c\u200f", "a\\u2066b\\u2069c\\u200f"),
        ("line\u2028sep\u2029x", "line\\u2028sep\\u2029x"),
        ("price$0_$x.png", "price$0_$x.png"),
        ("<script>.png", "<script>.png"),
        ("a|b`c\\d.png", "a|b`c\\d.png"),
        ("\U0001f469\u200d\U0001f52c caf\u00e9.png", "\U0001f469\u200d\U0001f52c caf\u00e9.png"),  # ZWJ emoji intact
    ],
)
def test_display_name(name, shown):
    assert display_name(name) == shown
    assert display_name(display_name(name)) == shown  # idempotent: safe to apply twice


def test_display_name_takes_bytes_and_paths():
    assert display_name(b"caf\xe9\n.png") == "caf\\xe9\\n.png"
    assert display_name(Path(os.fsdecode(b"d/caf\xe9.png"))) == "d/caf\\xe9.png"


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.text(), st.binary().map(os.fsdecode)))
def test_display_name_is_one_printable_utf8_line(text):
    shown = display_name(text)
    shown.encode("utf-8")  # strict: no lone surrogate
    assert len(shown.splitlines()) <= 1
    assert not UNSAFE & set(shown)
    if not (UNSAFE | {chr(c) for c in range(0xD800, 0xE000)}) & set(text):
        assert shown == text  # nothing else changed


def test_name_label_is_short_printable_and_keeps_both_ends():
    long = "L" * 280 + "_view_0042.png"
    label = name_label(long)
    assert len(label) == NAME_CHARS and "\u2026" in label
    assert label.startswith("LLLL") and label.endswith("_view_0042.png")
    assert name_label(os.fsdecode(b"caf\xe9_00.png")) == "caf\\xe9_00.png"
    assert name_label("short.png") == "short.png"
    assert name_label("x" * NAME_CHARS) == "x" * NAME_CHARS


def test_pipeline_messages_show_names_on_one_printable_line(tmp_path):
    """Too few views: the message lists each image by its display name (one line each, no lone surrogate), and a
    duplicate's reason names the earlier image likewise."""
    import cv2
    import numpy as np

    from circcal.board import Board
    from circcal.pipeline import TooFewImagesError, calibrate_images

    d = os.fsencode(tmp_path)
    names = [b"caf\xe9\nfake: line.png", b"copy.png"]
    png = cv2.imencode(".png", np.full((120, 160), 200, np.uint8))[1].tobytes()
    for n in names:
        with open(os.path.join(d, n), "wb") as f:
            f.write(png)
    with pytest.raises(TooFewImagesError) as exc:
        calibrate_images(
            [os.fsdecode(os.path.join(d, n)) for n in names], Board(4, 5, 10.0, 5.0), progress=False, jobs=1
        )
    msg = str(exc.value)
    msg.encode("utf-8")
    lines = msg.splitlines()
    assert len(lines) == 3 and "caf\\xe9\\nfake: line.png: " in lines[1]
    assert lines[2].endswith(
        "copy.png: identical content to " + display_name(os.path.join(d, names[0])) + " (given earlier): counted once"
    )
