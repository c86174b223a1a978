"""Subcommand registry: name -> (module under lesscli.cli, one-line help).

The one-line help is shown by ``less --help`` without importing the module, so listing the
commands never loads torch, cv2, trimesh, skimage or dynamixel_sdk. Each module exposes ``cli``,
a click command or group.
"""

COMMANDS: dict[str, tuple[str, str]] = {
    "info": ("info", "Describe a scan set, prediction file, checkpoint or label volume."),
    "subsample": ("subsample", "Keep every N-th step, K trajectories per scan, or a maximum length."),
    "concat": ("concat", "Concatenate scan sets that share sensor and units."),
    "split": ("split", "Split a scan set into train/val/test by insert or by scan."),
    "fetch": ("fetch", "Download published records (resumable, checksum-verified) from the public archive."),
    "import": ("import_", "Import the published HDF5 dataset layout (a folder or its zip) into a scan set."),
    "bench": ("bench", "Benchmarks: accuracy against time, ratios against in-run baselines."),
    "phantom": ("phantom",
                "Phantom label volumes (NIfTI) and geometry specs: catalogues, TOML sets, STL meshes."),
    "simulate": ("simulate", "Simulate palpation scans from a scene file (contact tiers, motions, effects)."),
    "lift": ("lift", "Scissor lift over Dynamixel servos: home, raise, lower, rotate, cycle; or emulate it."),
    "pretrain": ("pretrain",
                 "Self-supervised force-prediction pretraining of a LESS or GLOBAL representation."),
    "metrics": ("metrics",
                "Imaging metrics in mm (F1, centroid, ARSE, diameter, area/volume) per scan and set."),
    "image": ("image",
              "Tactile imaging: fit a 2D/3D image decoder on a representation, predict label images."),
    "stream": ("stream", "Real-time incremental imaging of a replayed scan set or live JSON-line samples."),
    "guide": ("guide", "Next touch locations that most reduce the image's uncertainty, from a partial scan."),
    "plot": ("plot", "Figures from files: training curves of one or more runs (plot log)."),
    "render": ("render", "PNG figures of predictions: truth | prediction | uncertainty, and time strips."),
    "mesh": ("mesh", "Per-class surface meshes (GLB/STL/PLY, mm) from a prediction or label NIfTI."),
    "mri-label": ("mri_label",
                  ("MRI scan of an insert -> label NIfTI (insert, pillar, inclusion); --synth makes test "
                   "scans.")),
    "noise-sweep": ("noise_sweep",
                    "Imaging accuracy under i.i.d. Gaussian pose noise: F1 per noise cell, plot."),
    "pose": ("pose", "Hand-held pose: AprilTag tracking, synthetic frames, robot calibration, accuracy."),
}
