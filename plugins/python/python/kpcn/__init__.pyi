from collections.abc import Mapping
from typing import Any, Optional

import numpy as np
import numpy.typing as npt

from ._kpcn import Denoiser as Denoiser, Image, Path, Progress, __version__ as __version__

class Error(Exception): ...
class InputError(Error, ValueError): ...
class IoError(Error, OSError): ...

def denoise(
    color: Optional[Image],
    *,
    albedo: Optional[Image] = None,
    normal: Optional[Image] = None,
    depth: Optional[Image] = None,
    diffuse: Optional[Image] = None,
    specular: Optional[Image] = None,
    variances: Optional[Mapping[str, Image]] = None,
    model: str = "auto",
    threads: Optional[int] = None,
    progress: Optional[Progress] = None,
) -> npt.NDArray[np.float32]: ...
def denoise_file(
    input: Path,
    output: Path,
    *,
    model: str = "auto",
    aovs: bool = False,
    layer: Optional[str] = None,
    view_layer: Optional[str] = None,
    separate: bool = False,
    in_place: bool = False,
    layout: Optional[str] = None,
    compression: Optional[str] = None,
    no_clobber: bool = False,
    max_memory: Optional[int] = None,
    threads: Optional[int] = None,
    progress: Optional[Progress] = None,
) -> list[dict[str, Any]]: ...
