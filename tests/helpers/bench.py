"""What the tests of ``gridrt bench`` share: reading a benchmark's CSV, and the checks every
benchmark's output folder passes (its CSV, plots, machine record and summary)."""

import csv
import json

from PIL import Image


def read_csv(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def check_outputs(out, csv_name, pngs):
    rows = read_csv(out / csv_name)
    assert rows
    for name in pngs:
        with Image.open(out / name) as im:
            assert im.size[0] > 200 and im.size[1] > 150
    info = json.loads((out / "machine.json").read_text())
    for k in ("cpu", "cores", "threads_used", "python", "numpy", "numba", "embreex", "commit", "date"):
        assert k in info, k
    summary = (out / "summary.md").read_text()
    assert "## Machine" in summary and info["cpu"] in summary
    return rows, summary
