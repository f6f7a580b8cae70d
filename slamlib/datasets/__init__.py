"""Loaders for the real robot logs shipped (compressed) in ``slamlib/data``.

Each data set keeps its attribution in ``slamlib/data/<name>/ATTRIBUTION.md``.
"""

from importlib import resources
from pathlib import Path

__all__ = ["data_path", "CmuLog", "load_cmu_map", "load_cmu_log", "MRCLAMRun", "load_mrclam",
           "PoseGraph", "PoseGraph3D", "City10000", "load_g2o", "load_g2o3d", "load_sphere2500", "load_city10000",
           "load_intel", "load_m3500", "VictoriaRun", "load_victoria_park",
           "SiftKeys", "load_balbianello_keys", "load_balbianello_image", "SfmProblem", "load_bundler", "load_bal",
           "load_balbianello", "load_dubrovnik", "StereoVOData", "load_kitti_vo",
           "stereo_vo_segment", "simulate_stereo_drive"]


def data_path(*parts: str) -> Path:
    """Path of a file shipped in ``slamlib/data`` (e.g. ``data_path("cmu_wean", "wean.dat.gz")``)."""
    path = Path(str(resources.files("slamlib"))) / "data"
    for p in parts:
        path = path / p
    if not path.exists():
        raise FileNotFoundError(f"no data file {path} in the installed slamlib package")
    return path


from .cmu import CmuLog, load_cmu_log, load_cmu_map  # noqa: E402
from .mrclam import MRCLAMRun, load_mrclam  # noqa: E402
from .g2o import City10000, PoseGraph, PoseGraph3D, load_city10000, load_g2o, load_g2o3d, load_sphere2500, load_intel, load_m3500  # noqa: E402
from .victoria import VictoriaRun, load_victoria_park  # noqa: E402
from .sfm import (SiftKeys, SfmProblem, load_balbianello_image, load_bal, load_balbianello,  # noqa: E402
                  load_balbianello_keys, load_bundler, load_dubrovnik)
from .kitti_vo import StereoVOData, load_kitti_vo, stereo_vo_segment  # noqa: E402
from .kitti_vo_sim import simulate_stereo_drive  # noqa: E402
