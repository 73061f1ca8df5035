"""The README's Python example runs as written (a newcomer pastes it): it calibrates the rendered fixture, its
verdict says the cross-validation ran, and it writes the model it says it writes."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_readme_python_example_runs(tmp_path):
    code = re.search(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S).group(1)
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    out = run.stdout
    assert "cross-validation: consistent" in out, out  # run, not "not run"
    assert "0 images left out" in out
    line = next(ln for ln in out.splitlines() if ln.startswith("{'fx': "))
    stds = dict(re.findall(r"'(\w+)': '([^']+)'", line))
    assert len(stds) == 9 and all(float(v) > 0 for v in stds.values()), line  # no sigma printed as 0.0
    from circcal import load_model

    cam = load_model(tmp_path / "model.json")
    assert abs(cam.fx - 550.0) < 1.0 and cam.lens == "opencv5"  # the small-noisy scenario's camera: fx 550 px
