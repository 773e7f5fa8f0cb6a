"""Checks a `hetcomm demo` run with Tango as a bridged ROS robot against the simulated run.

    python3 scripts/tango-follows.py ROS_OUT SIM_OUT

ROS_OUT and SIM_OUT are the `--out` directories of the run with the ROS rover (ROS 1 or 2)
and of the simulated run (virtual time, every rover ours). Tango follows when the leader's
four commands reach it in order (as its odometry shows them) and each second its pose is
within 10 units (1 s of driving) and 15 degrees of the simulated run's. Used by
scripts/ros1-test.sh and scripts/ros2-test.sh; needs only the standard library.
"""
import csv
import math
import sys


def load(d, name):
    with open(f"{d}/{name}") as f:
        return list(csv.DictReader(f))


def tango(d):
    return {round(float(r["t_s"]), 3): r for r in load(d, "poses.csv") if r["rover"] == "Tango"}


def main():
    ros, sim = sys.argv[1], sys.argv[2]
    codes = [int(r["code"]) for r in load(ros, "commands.csv") if r["rover"] == "Tango"]
    assert codes == [1, 0, 1, 0], f"Tango's commands, seen in its odometry: {codes}"
    a, b = tango(ros), tango(sim)
    assert len(a) >= 140, f"only {len(a)} poses of Tango"
    worst = (0.0, 0.0, None)
    for t in sorted(b):
        if t not in a or abs(t - round(t)) > 1e-9:
            continue
        p, q = a[t], b[t]
        d = math.hypot(float(p["x"]) - float(q["x"]), float(p["y"]) - float(q["y"]))
        h = abs((float(p["theta_deg"]) - float(q["theta_deg"]) + 180) % 360 - 180)
        assert d <= 10.0 and h <= 15.0, f"t={t}: Tango {d:.2f} units / {h:.1f} deg off the simulated run"
        worst = max(worst, (d, h, t), key=lambda w: w[0])
    assert worst[2] is not None, "no whole second in common with the simulated run"
    end = max(a)
    print(
        f"Tango followed: {len(codes)} commands in order; at most {worst[0]:.2f} units from the "
        f"simulated run (t={worst[2]}); ends at ({float(a[end]['x']):.2f}, {float(a[end]['y']):.2f}), "
        f"simulated ({float(b[end]['x']):.2f}, {float(b[end]['y']):.2f})"
    )


if __name__ == "__main__":
    main()
