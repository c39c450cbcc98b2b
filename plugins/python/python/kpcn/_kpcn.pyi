"""Types of the native part of `kpcn` (re-exported by the package)."""

from collections.abc import Callable, Mapping
from os import PathLike
from typing import Any, Optional, Union

import numpy as np
import numpy.typing as npt

__version__: str

Image = npt.NDArray[Union[np.float32, np.float16]]
Progress = Callable[[float], Optional[bool]]
Path = Union[str, PathLike[str]]

class Denoiser:
    """A loaded model (or `auto`'s two), reused across frames; safe to share between threads."""

    def __init__(self, model: str = "auto", *, threads: Optional[int] = None, max_memory: Optional[int] = None) -> None: ...
    @property
    def model(self) -> str: ...
    def denoise(
        self,
        color: Optional[Image],
        *,
        albedo: Optional[Image] = None,
        normal: Optional[Image] = None,
        depth: Optional[Image] = None,
        diffuse: Optional[Image] = None,
        specular: Optional[Image] = None,
        variances: Optional[Mapping[str, Image]] = None,
        progress: Optional[Progress] = None,
    ) -> npt.NDArray[np.float32]:
        """Denoises one frame held in numpy arrays; returns the colour, (H, W, 3) float32."""
    def denoise_file(
        self,
        input: Path,
        output: Path,
        *,
        aovs: bool = False,
        layer: Optional[str] = None,
        view_layer: Optional[str] = None,
        separate: bool = False,
        in_place: bool = False,
        layout: Optional[str] = None,
        compression: Optional[str] = None,
        no_clobber: bool = False,
        progress: Optional[Progress] = None,
    ) -> list[dict[str, Any]]:
        """Denoises a layered EXR into `output` as `kpcn denoise INPUT -o OUTPUT` does."""
