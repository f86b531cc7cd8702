"""avatarkit: one portrait in, an animated compositional 3D Gaussian head avatar out."""
from importlib.metadata import PackageNotFoundError, version as _version

from avatarkit.errors import AvatarKitError, FormatError, InputError
from avatarkit.gaussians import GaussianSet

try:
    __version__ = _version("avatarkit")
except PackageNotFoundError:  # running from a source tree without an install
    __version__ = "0.0.0+unknown"

__all__ = ["AvatarKitError", "FormatError", "InputError", "GaussianSet", "__version__"]
