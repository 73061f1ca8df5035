"""calibrate-rig's ``--fix-*`` flags per camera: ``--fix-k3 NAME`` holds one camera's k3; a plain ``--fix-k3`` holds
every camera's, except a fisheye's in a rig that mixes it with pinhole lenses (its k3 is cv2.fisheye's theta^6 term,
not the pinhole's r^6: holding it at 0 biased its k4); ``--kalibr`` names every camera that blocks it and flags that
clear each."""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np
import pytest

from circcal import cli
from circcal.commands.rig import _check_formats, _options
from circcal.errors import InputError
from circcal.fixtures.rig import rig_observations, rig_scenario
from circcal.rig import calibrate_rig_points

GRID = ["--grid", "8x11", "--pitch", "15mm"]


def _args(*words: str):
    return cli.build_parser().parse_args(
        ["calibrate-rig", "--camera", "pinhole=L", "--camera", "fish=R", *GRID, "--out", "rig.json", *words]
    )


def _held(options) -> dict[str, tuple[str, ...]]:
    return {n: o.fixed for n, o in options.items()}


def test_a_plain_fix_k3_leaves_a_fisheyes_k3_free_in_a_mixed_rig_and_says_so(capsys):
    args = _args("--lens", "fish=fisheye", "--fix-k3")
    held = _held(_options(args, ["pinhole", "fish"]))
    assert held == {"pinhole": ("k3",), "fish": ()}
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and "--fix-k3 holds k3 of pinhole only, not of fish" in out[0], out
    assert "theta^6" in out[0] and "--fix-k3 fish holds it" in out[0]


@pytest.mark.parametrize(
    "words,expected",
    [
        (["--fix-k3", "fish"], {"pinhole": (), "fish": ("k3",)}),  # named: the fisheye's theta^6 term
        (["--fix-k3=pinhole"], {"pinhole": ("k3",), "fish": ()}),
        (["--fix-k3", "pinhole", "--fix-k3", "fish"], {"pinhole": ("k3",), "fish": ("k3",)}),
        (["--fix-k3", "--fix-k3", "fish"], {"pinhole": ("k3",), "fish": ("k3",)}),
        (["--fix-k2", "--fix-principal-point", "fish"], {"pinhole": ("k2",), "fish": ("cx", "cy")}),
        (["--fix-tangential", "pinhole"], {"pinhole": ("p1", "p2"), "fish": ()}),
    ],
)
def test_hold_flags_name_cameras(words, expected, capsys):
    assert _held(_options(_args("--lens", "fish=fisheye", *words), ["pinhole", "fish"])) == expected


def test_a_plain_flag_still_holds_every_camera_where_it_means_one_thing(capsys):
    """Backwards compatible: two pinhole lenses, or two fisheyes (whose k3 is one coefficient), all held."""
    assert _held(_options(_args("--fix-k3"), ["pinhole", "fish"])) == {"pinhole": ("k3",), "fish": ("k3",)}
    both = _held(_options(_args("--lens", "fisheye", "--fix-k3"), ["pinhole", "fish"]))
    assert both == {"pinhole": ("k3",), "fish": ("k3",)}
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize(
    "words,expected",
    [
        (["--fix-k3", "top"], "--fix-k3 top: no camera 'top' (cameras: pinhole, fish)"),
        (["--fix-k3", "fish", "--fix-k3=fish"], "--fix-k3 fish: camera 'fish' given twice"),
        (["--fix-tangential", "fish"], "--fix-tangential fish: the fisheye lens model has no p1, p2 to hold fixed"),
        (["--fix-tangential"], "--fix-tangential: the fisheye lens model has no p1, p2 to hold fixed; name the "),
    ],
)
def test_bad_hold_flags_are_one_line_naming_the_flag(words, expected):
    with pytest.raises(InputError) as err:
        _options(_args("--lens", "fish=fisheye", *words), ["pinhole", "fish"])
    assert expected in str(err.value) and "\n" not in str(err.value)


def test_the_fisheyes_k3_is_estimated_not_held_at_zero(capsys):
    """The `fisheye` rig (its fisheye's k3 is 0.004) calibrated with the options a plain --fix-k3 gives: the pinhole
    camera's k3 held, the fisheye's k1..k4 within 4.5 stated sigmas of the truth (held at 0, k3 was 0.004 off and
    k4 absorbed it)."""
    sc = rig_scenario("fisheye")
    options = _options(_args("--lens", "fish=fisheye", "--fix-k3"), list(sc.rig.names))
    sizes = {n: (c.width, c.height) for n, c in zip(sc.rig.names, sc.rig.cameras)}
    cal = calibrate_rig_points(rig_observations(sc, 0.05, 1), sizes, options)
    std = cal.std()
    pin = len(sc.rig.cameras[0].intrinsics)
    assert std[pin - 1] == 0.0 and cal.rig.cameras[0].dist[4] == 0.0  # the pinhole's k3: held
    fish_true, fish = sc.rig.cameras[1], cal.rig.cameras[1]
    s = std[pin + 4 : pin + 8]
    assert np.all(s > 0), s
    z = (np.asarray(fish.dist) - np.asarray(fish_true.dist)) / s
    assert np.all(np.abs(z) < 4.5), z


def _kalibr_refusal(tmp_path: Path, *words: str) -> str:
    args = cli.build_parser().parse_args(
        ["calibrate-rig", "--camera", "left=L", "--camera", "right=R", *GRID, "--out", str(tmp_path / "rig.json")]
        + ["--kalibr", str(tmp_path / "camchain.yaml"), *words]
    )
    names = ["left", "right"]
    with pytest.raises(InputError) as err:
        _check_formats(args, names, _options(args, names))
    return str(err.value)


def test_kalibr_names_every_camera_that_blocks_it_and_a_command_that_works(tmp_path, capsys):
    """The toe rig (opencv5 left, rational right): both cameras named, and the flags the message gives, put in place
    of right's --lens, pass the check."""
    msg = _kalibr_refusal(tmp_path, "--lens", "right=rational")
    assert "\n" not in msg
    assert "'left' (opencv5 with k3 free), 'right' (rational) have more" in msg, msg
    assert "(--lens right=opencv5 in place of rational; or a fisheye" in msg, msg
    words = shlex.split(msg.split("; give ", 1)[1].split(" (", 1)[0])
    assert words == ["--fix-k3", "left", "--lens", "right=opencv5", "--fix-k3", "right"], words
    args = cli.build_parser().parse_args(
        ["calibrate-rig", "--camera", "left=L", "--camera", "right=R", *GRID, "--out", str(tmp_path / "rig.json")]
        + ["--kalibr", str(tmp_path / "camchain.yaml"), *words]
    )
    assert _check_formats(args, ["left", "right"], _options(args, ["left", "right"])) == "json"
    # a pinhole + fisheye rig: the pinhole camera named, its own flag given
    msg = _kalibr_refusal(tmp_path, "--lens", "right=fisheye")
    assert "camera 'left' (opencv5 with k3 free) has more; give --fix-k3 left (or a fisheye" in msg, msg
