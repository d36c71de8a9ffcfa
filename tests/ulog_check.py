"""Reads an export of `uquad export --format ulog` with pyulog, as tests/export.rs asks, and
compares it with the run folder's text logs.

Usage: ulog_check.py FILE.ulg RUN_DIR. Prints one JSON line: the topics `ulog_info` lists,
the largest difference of each compared column from the text logs (0.0: equal), the counts of
rows, parameters and logged messages. Exits 1 with the reason when something cannot be read.
"""

import json
import math
import os
import subprocess
import sys

from pyulog import ULog


def rows(path):
    """A text log's rows as lists of fields; [] when the file does not exist."""
    if not os.path.exists(path):
        return []
    with open(path) as f:
        return [line.split() for line in f if line.strip()]


def micros(text):
    """A time column ("12.126526", seconds with µs) as an integer of µs, exactly."""
    sign = -1 if text.startswith("-") else 1
    whole, _, frac = text.lstrip("-").partition(".")
    return sign * (int(whole) * 1_000_000 + int((frac + "000000")[:6]))


def worst(a, b):
    """Largest |a − b| (NaN equal to NaN); the lengths when they differ."""
    if len(a) != len(b):
        return f"lengths differ: {len(a)} vs {len(b)}"
    d = 0.0
    for x, y in zip(a, b):
        if math.isnan(x) and math.isnan(y):
            continue
        d = max(d, abs(x - y))
    return d


def main():
    ulg, run = sys.argv[1], sys.argv[2]
    info = subprocess.run(
        [os.path.join(os.path.dirname(sys.executable), "ulog_info"), ulg],
        capture_output=True, text=True, check=True,
    ).stdout
    log = ULog(ulg)
    data = {d.name: d.data for d in log.data_list}
    # ulog_info lists each topic as " name (multi id, size)".
    listed = {line.split()[0] for line in info.splitlines() if line.startswith(" ") and "(" in line}
    topics = sorted(t for t in data if t in listed)
    x_hat = [[float(v) for v in r] for r in rows(os.path.join(run, "x_hat.log"))]
    k_in = rows(os.path.join(run, "kalman_in.log"))
    w = rows(os.path.join(run, "w.log"))
    sp = rows(os.path.join(run, "setpoint.log"))
    lp = data["vehicle_local_position"]
    n = len(k_in)
    diff = {
        "local_position.x": worst(list(lp["x"][:n]), [r[0] for r in x_hat[:n]]),
        "local_position.y": worst(list(lp["y"][:n]), [-r[1] for r in x_hat[:n]]),
        "local_position.z": worst(list(lp["z"][:n]), [-r[2] for r in x_hat[:n]]),
        "local_position.timestamp": worst(
            [float(t) for t in lp["timestamp"][:n]], [float(micros(r[0])) for r in k_in]
        ),
        "sensor_combined.gyro_rad[1]": worst(
            list(data["sensor_combined"]["gyro_rad[1]"]), [-float(r[7]) for r in k_in]
        ),
        "actuator_outputs.timestamp": worst(
            [float(t) for t in data["actuator_outputs"]["timestamp"]],
            [float(micros(r[0])) for r in w],
        ),
    }
    for m in range(4):
        diff[f"actuator_outputs.output[{m}]"] = worst(
            list(data["actuator_outputs"][f"output[{m}]"]), [float(r[m + 1]) for r in w]
        )
    raw = rows(os.path.join(run, "imu_raw.log"))
    diff["uquad_imu_raw.acc_counts[2]"] = worst(
        [float(v) for v in data["uquad_imu_raw"]["acc_counts[2]"]], [float(r[5]) for r in raw]
    )
    if sp:
        lps = data["vehicle_local_position_setpoint"]
        diff["local_position_setpoint.z"] = worst(list(lps["z"]), [-float(r[3]) for r in sp])
    # A track for Google Earth from the fixes, as people make one (ulog2kml reads lat, lon
    # and alt).
    kml_bytes = None
    if "vehicle_gps_position" in data:
        kml = ulg + ".kml"
        subprocess.run(
            [os.path.join(os.path.dirname(sys.executable), "ulog2kml"), ulg, "-o", kml],
            capture_output=True, text=True, check=True,
        )
        kml_bytes = os.path.getsize(kml)
        gps = [
            r for r in rows(os.path.join(run, "gps.log")) if len(r) > 5 and r[0] != "#"
        ]
        diff["vehicle_gps_position.altitude_msl_m"] = worst(
            list(data["vehicle_gps_position"]["altitude_msl_m"]), [float(r[5]) for r in gps]
        )
    out = {
        "kml_bytes": kml_bytes,
        "topics": topics,
        "diff": diff,
        "rows": {t: len(d["timestamp"]) for t, d in data.items()},
        "params": len(log.initial_parameters),
        "messages": [m.message for m in log.logged_messages],
        "sys_name": log.msg_info_dict.get("sys_name"),
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
