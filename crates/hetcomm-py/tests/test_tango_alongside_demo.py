"""The Python Tango (examples/python/tango.py) runs alongside the Rust leader–follower demo:
`hetcomm demo --realtime --external Tango` runs Alpha, Charlie and the virtual environments; the
Python process is Tango, reached over UDP. Tango must receive the four commands in order and
the Rust virtual environment must see it make the same two left turns as the others."""

from __future__ import annotations

import re

from conftest import CLI, PYTHON, ROOT, cli, free_ports

TANGO = ROOT / "examples" / "python" / "tango.py"
FLEET = ROOT / "examples" / "python" / "leader-follower-python.toml"


def pose_rows(demo_stdout: str, rover: str):
    """(t, x, y, theta) rows of a rover's location table printed by the demo."""
    block = demo_stdout.split(f"{rover} location data", 1)[1].split("\n\n", 1)[0]
    rows = []
    for line in block.splitlines()[2:]:
        fields = line.split()
        if len(fields) == 4:
            rows.append(tuple(float(f) for f in fields))
    return rows


def test_python_tango_follows_the_rust_leader(tmp_path, children):
    # The shipped fleet with free ports.
    text = FLEET.read_text()
    olds = sorted(set(re.findall(r"127\.0\.0\.1:(\d+)", text)))
    for old, new in zip(olds, free_ports("udp", len(olds))):
        text = text.replace(f"127.0.0.1:{old}", f"127.0.0.1:{new}")
    fleet = tmp_path / "fleet.toml"
    fleet.write_text(text)
    # Its keys, as its README says to make them.
    made = cli("keygen", "--fleet", str(fleet), "--out", str(tmp_path / "keys"))
    assert made.returncode == 0, made

    tango = children([PYTHON, str(TANGO), str(fleet), "--duration", "30", "--exit-on-stop"])
    tango.wait_stdout(lambda l: l.startswith("Tango: ready on lan udp://127.0.0.1:"))
    demo = children([CLI, "demo", "--realtime", "--fleet", str(fleet), "--external", "Tango",
                     "--out", str(tmp_path / "out")])
    assert demo.wait(timeout=60) == 0, demo.stderr_lines

    commands = [l for l in tango.stdout_lines if l.startswith("Tango: command ")]
    assert [int(l.split()[2]) for l in commands] == [1, 0, 1, 0], tango.stdout_lines
    assert all("from Charlie.Plan" in l for l in commands)

    # The Rust VE logged Tango's pose: two pivots (x, y still, θ turning) between straights.
    out = "\n".join(demo.stdout_lines)
    rows = pose_rows(out, "Tango")
    assert len(rows) >= 15, out
    turns = 0
    turning = False
    for (t0, x0, y0, th0), (t1, x1, y1, th1) in zip(rows, rows[1:]):
        moved = abs(x1 - x0) > 1e-6 or abs(y1 - y0) > 1e-6
        rotated = abs(th1 - th0) > 1e-6
        if rotated and not moved and not turning:
            turns += 1
        turning = rotated and not moved
    assert turns == 2, rows
    assert (tmp_path / "out" / "trajectory.png").stat().st_size > 10_000
