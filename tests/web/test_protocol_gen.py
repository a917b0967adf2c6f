"""``web/src/protocol.gen.ts`` is what the server's code gives (``python -m server.webtypes``),
and the web console takes the frame layout and a command's stages from it, not by hand.

The first test is plain Python. The second runs the console's own TypeScript (bundled by
the project's esbuild, run by node) and compares what it computes with the Python
definitions; it is skipped, with the reason, when the console's node_modules are missing.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from server import webtypes
from server.services.command_stages import FINAL_STAGES, STAGE_RANK
from server.storage.models import MAX_STORED_JOINTS
from telemetry.layout import DEFAULT_LAYOUT, MAX_JOINTS, MAX_WHEELS, FrameLayout

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

WEB = Path(__file__).resolve().parents[2] / "web"
SRC = WEB / "src"
ESBUILD = WEB / "node_modules" / ".bin" / "esbuild"


def test_the_generated_file_is_what_the_server_gives() -> None:
    assert webtypes.TARGET == SRC / "protocol.gen.ts"
    assert webtypes.TARGET.read_text() == webtypes.generate(), (
        "web/src/protocol.gen.ts is stale: run python -m server.webtypes"
    )
    assert webtypes.main(["--check"]) == 0


def test_the_check_fails_on_a_stale_file(tmp_path: Path) -> None:
    stale = tmp_path / "protocol.gen.ts"
    stale.write_text(webtypes.generate().replace('"cancelled"', '"canceled"'))
    assert webtypes.main(["--check", "--out", str(stale)]) == 1
    assert webtypes.main(["--out", str(stale)]) == 0
    assert webtypes.main(["--check", "--out", str(stale)]) == 0


def test_no_web_module_hand_writes_the_stages_or_the_frame_fields() -> None:
    """The rank table and the vectors' column names are the generated file's alone."""
    forbidden = [
        re.compile(r"\b(executed|rejected|expired|cancelled)\s*:\s*\d"),  # a rank table
        re.compile(r"""["'](qx|wx|hw1|tqx|ws1)["']"""),  # a vector's column names
        re.compile(r"MAX_JOINTS\s*=\s*\d"),
    ]
    found = []
    for path in sorted(SRC.rglob("*.ts")):
        if path.name == "protocol.gen.ts":
            continue
        for pattern in forbidden:
            found += [f"{path.name}: {m.group(0)}" for m in pattern.finditer(path.read_text())]
    assert found == []


_PROBE = """
import { layoutColumns } from "{src}/layout";
import { COMMAND_STAGES, FINAL_STAGES, MAX_STORED_JOINTS, STAGE_RANK } from "{src}/protocol.gen";
import { DEFAULT_JOINTS, MAX_JOINTS, RAW_FIELDS, rawFields } from "{src}/store";

const layouts: Record<string, string[]> = {};
for (let n = 1; n <= {max_joints}; n++)
  for (let k = 1; k <= {max_wheels}; k++) layouts[`${n},${k}`] = layoutColumns(n, k);
const raw: Record<string, string[]> = {};
for (let n = 1; n <= {max_joints}; n++) raw[n] = rawFields(n);
console.log(JSON.stringify({
  layouts, raw, RAW_FIELDS, DEFAULT_JOINTS, MAX_JOINTS, MAX_STORED_JOINTS,
  COMMAND_STAGES, STAGE_RANK, FINAL_STAGES,
}));
"""


def test_the_console_computes_the_layout_and_stages_the_server_has(tmp_path: Path) -> None:
    node = shutil.which("node")
    if node is None or not ESBUILD.exists():
        pytest.skip("no node or no web/node_modules (cd web && npm ci)")
    probe = tmp_path / "probe.ts"
    probe.write_text(
        _PROBE.replace("{src}", str(SRC))
        .replace("{max_joints}", str(MAX_JOINTS))
        .replace("{max_wheels}", str(MAX_WHEELS))
    )
    bundle = tmp_path / "probe.mjs"
    subprocess.run(
        [str(ESBUILD), str(probe), "--bundle", "--platform=node", "--format=esm",
         f"--outfile={bundle}", "--log-level=warning"],
        check=True, cwd=WEB, timeout=120,
    )  # fmt: skip
    out = subprocess.run(
        [node, str(bundle)], check=True, capture_output=True, text=True, timeout=60
    ).stdout
    got = json.loads(out)
    for n in range(1, MAX_JOINTS + 1):
        for k in range(1, MAX_WHEELS + 1):
            assert got["layouts"][f"{n},{k}"] == list(FrameLayout(n, k).columns), (n, k)
    # The store keeps joints, targets, the quaternion, the rates and the wheel momentum.
    for n in range(1, MAX_JOINTS + 1):
        names = dict(FrameLayout(n, 3).vectors)
        kept = [
            "joints_rad",
            "joint_targets_rad",
            "quat_orbit_from_base_xyzw",
            "omega_base_in_base_radps",
            "wheel_momentum_nms",
        ]
        assert got["raw"][str(n)] == [c for array in kept for c in names[array]], n
    assert got["RAW_FIELDS"] == got["raw"][str(MAX_STORED_JOINTS)]
    assert got["MAX_JOINTS"] == got["MAX_STORED_JOINTS"] == MAX_STORED_JOINTS
    assert got["DEFAULT_JOINTS"] == DEFAULT_LAYOUT.n_joints
    assert got["COMMAND_STAGES"] == list(STAGE_RANK)
    assert got["STAGE_RANK"] == STAGE_RANK
    assert got["FINAL_STAGES"] == list(FINAL_STAGES)
