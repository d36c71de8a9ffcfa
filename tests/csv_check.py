"""Reads the CSV folder of `uquad export --format csv` with Python's csv module, as
tests/export.rs asks. Usage: csv_check.py OUT_DIR RUN_DIR. Prints one JSON line: the files,
the headers that name no unit, and the largest difference of x_hat.csv's z from x_hat.log."""

import csv
import json
import os
import sys


def main():
    out, run = sys.argv[1], sys.argv[2]
    files = sorted(f[:-4] for f in os.listdir(out) if f.endswith(".csv"))
    no_unit = []
    tables = {}
    for name in files:
        with open(os.path.join(out, name + ".csv"), newline="") as f:
            table = list(csv.reader(f))
        no_unit += [f"{name}: {h}" for h in table[0] if not (h.endswith("]") and " [" in h)]
        tables[name] = table
    with open(os.path.join(run, "x_hat.log")) as f:
        z_log = [float(line.split()[2]) for line in f if line.strip()]
    header = tables["x_hat"][0]
    col = header.index("z up [m]")
    z_csv = [float(r[col]) for r in tables["x_hat"][1:]]
    diff = max(abs(a - b) for a, b in zip(z_csv, z_log)) if len(z_csv) == len(z_log) else None
    print(json.dumps({"files": files, "headers_without_unit": no_unit, "x_hat_z_diff": diff}))


if __name__ == "__main__":
    main()
