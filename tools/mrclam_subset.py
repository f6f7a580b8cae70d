"""Cut the subset of MRCLAM Dataset 6 that ships in ``slamlib/data/mrclam`` from the original files.

Usage: ``python tools/mrclam_subset.py ORIGINAL_FOLDER [--out slamlib/data/mrclam] [--robots 1 2 3 4 5]``

What it writes is described in ``slamlib/data/mrclam/ATTRIBUTION.md``:

* ``Barcodes.dat.gz``, ``Landmark_Groundtruth.dat.gz``, ``RobotN_Measurement.dat.gz``: the
  original text, recompressed;
* ``RobotN_Odometry.dat.gz``: the original lines where ``(v, w)`` changes, plus the first and the
  last line (lossless for a zero-order hold);
* ``RobotN_Groundtruth.dat.gz``: the Vicon poses linearly interpolated onto the 10 Hz grid of
  multiples of 0.1 s inside the track (heading unwrapped first, wrapped to ``[-pi, pi)`` after),
  rounded to 4 decimals.

Every file is written with gzip level 9 and modification time 0, so a rerun gives the same bytes.
"""

from __future__ import annotations

import argparse
import gzip
import io
from pathlib import Path

import numpy as np

HEAD = ("# UTIAS Multi-Robot Cooperative Localization and Mapping Dataset\n"
        "# produced by Keith Leung (keith.leung@robotics.utias.utoronto.ca) 2009\n")
ODO_HEAD = HEAD + (
    "# Subset for slamlib: only the rows where (v, w) changes, plus the last row (lossless for a\n"
    "# zero-order hold: each command holds until the next row). See ATTRIBUTION.md.\n"
    "# Odometry Data Format:\n"
    "# Time [s]    forward velocity [m/s]    angular velocity[rad/s]\n")
GT_HEAD = HEAD + (
    "# Subset for slamlib: Vicon poses linearly interpolated to a 10 Hz grid (heading unwrapped\n"
    "# before interpolating, then wrapped to [-pi, pi)), rounded to 0.1 mm / 0.1 mrad. See ATTRIBUTION.md.\n"
    "# Robot Groundtruth Data Format:\n"
    "# Time [s]    x [m]    y [m]    orientation [rad]\n")


def _read_text(path: Path) -> str:
    with gzip.open(path, "rt") as f:
        return f.read()


def _write(path: Path, text: str) -> None:
    buf = io.BytesIO()
    with gzip.GzipFile(filename="", mode="wb", fileobj=buf, compresslevel=9, mtime=0) as f:
        f.write(text.encode())
    path.write_bytes(buf.getvalue())


def _data_lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def odometry_subset(text: str) -> str:
    """The change points of ``(v, w)``, the first and the last line, with the original tokens."""
    rows = [ln.split() for ln in _data_lines(text)]
    vals = np.array([[float(r[1]), float(r[2])] for r in rows])
    keep = np.ones(len(rows), dtype=bool)
    keep[1:] = np.any(np.diff(vals, axis=0) != 0, axis=1)
    keep[-1] = True
    return ODO_HEAD + "".join("\t".join(r) + "\n" for r, k in zip(rows, keep) if k)


def groundtruth_subset(text: str) -> str:
    """Vicon poses interpolated onto the multiples of 0.1 s inside the track."""
    gt = np.loadtxt(io.StringIO(text), comments="#", ndmin=2)
    k0, k1 = int(np.ceil(gt[0, 0] * 10 - 1e-6)), int(np.floor(gt[-1, 0] * 10 + 1e-6))
    t = np.arange(k0, k1 + 1) / 10
    th = np.interp(t, gt[:, 0], np.unwrap(gt[:, 3]))
    th = (th + np.pi) % (2 * np.pi) - np.pi
    x, y = np.interp(t, gt[:, 0], gt[:, 1]), np.interp(t, gt[:, 0], gt[:, 2])
    return GT_HEAD + "".join(f"{a:.1f}\t{b:.4f}\t{c:.4f}\t{d:.4f}\n" for a, b, c, d in zip(t, x, y, th))


def _original(text):
    """An argparse type: a folder holding the original dataset's files."""
    path = Path(text)
    if not (path / "Barcodes.dat.gz").is_file():
        raise argparse.ArgumentTypeError(f"{text!r} is not a folder of the original MRCLAM_Dataset6 files "
                                         "(no Barcodes.dat.gz in it)")
    return path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("original", type=_original, help="folder of the original MRCLAM_Dataset6 files")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "slamlib" / "data" / "mrclam")
    ap.add_argument("--robots", type=int, nargs="+", default=[1, 2, 3, 4, 5], choices=range(1, 6))
    args = ap.parse_args(argv)
    for name in ("Barcodes.dat.gz", "Landmark_Groundtruth.dat.gz"):
        _write(args.out / name, _read_text(args.original / name))
    for r in args.robots:
        _write(args.out / f"Robot{r}_Measurement.dat.gz", _read_text(args.original / f"Robot{r}_Measurement.dat.gz"))
        _write(args.out / f"Robot{r}_Odometry.dat.gz", odometry_subset(_read_text(args.original / f"Robot{r}_Odometry.dat.gz")))
        _write(args.out / f"Robot{r}_Groundtruth.dat.gz",
               groundtruth_subset(_read_text(args.original / f"Robot{r}_Groundtruth.dat.gz")))
        print(f"robot {r}: written")


if __name__ == "__main__":
    main()
