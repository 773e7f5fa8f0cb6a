"""examples/python/tango.py, the Python Tango rover, runs alongside Rust systems over UDP: the
`hetcomm` CLI plays its leader Charlie (sending Commands) and its virtual environment (listening
for Wheels); Tango must follow the commands."""

from __future__ import annotations

import json

from conftest import CLI, PYTHON, ROOT, cli, ip_fleet

TANGO = ROOT / "examples" / "python" / "tango.py"


def command(fleet, code: int):
    sent = cli("send", str(fleet), "--as", "Charlie", "--to", "Tango", "--module", "Plan",
               "--type", "0", "--json", json.dumps({"code": code}))
    assert sent.returncode == 0, sent
    assert sent.stdout.startswith("Tango: delivered"), sent.stdout


def test_tango_follows_commands_over_udp(tmp_path, children):
    fleet = ip_fleet(tmp_path, "udp", ["Charlie", "Tango", "VirtualEnv3"])
    env = children([CLI, "listen", str(fleet), "--as", "VirtualEnv3", "--module", "World", "--json", "--timeout", "60"])
    env.wait_stderr(lambda l: l.startswith("listening as "))
    tango = children([PYTHON, str(TANGO), str(fleet), "--exit-on-stop", "--duration", "60"])
    tango.wait_stdout(lambda l: l.startswith("Tango: ready on lan udp://127.0.0.1:"))

    def next_wheels():
        line = json.loads(env.next_stdout())
        assert line["from_system"] == "Tango" and line["from_module"] == "Act" and line["type"] == 1
        return line["payload"]

    # Before any command: straight ahead.
    assert next_wheels() == {"left": 1.0, "right": 1.0}

    def follow(code, wheels):
        command(fleet, code)
        tango.wait_stdout(lambda l: l.startswith(f"Tango: command {code} from Charlie.Plan"))
        # The environment sees the new speeds within a few control periods.
        for _ in range(50):
            if next_wheels() == wheels:
                return
        raise AssertionError(f"the environment never saw {wheels} after command {code}")

    follow(1, {"left": -10.0, "right": 10.0})  # turn left
    follow(0, {"left": 1.0, "right": 1.0})  # straight
    follow(2, {"left": 0.0, "right": 0.0})  # stop: Tango exits
    assert tango.wait(timeout=20) == 0
    assert tango.stdout_lines[-1] == "Tango: done after 3 commands"
