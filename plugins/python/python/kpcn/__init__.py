"""kpcn: a kernel-predicting Monte Carlo render denoiser.

Denoise numpy arrays (``denoise``) or layered EXR files (``denoise_file``, as the
``kpcn denoise`` command does); ``Denoiser`` keeps a model loaded across frames. The work
runs with the GIL released, on all cores unless ``threads`` says otherwise; Ctrl-C cancels
it within a tile.
"""

from __future__ import annotations


class Error(Exception):
    """Any kpcn failure; the message says what went wrong and what to do."""


class InputError(Error, ValueError):
    """A bad argument, array or file content (missing channels, wrong shape, unknown model)."""


class IoError(Error, OSError):
    """A file could not be opened, read or written."""


from ._kpcn import Denoiser, __version__  # noqa: E402  (the classes above come first: it raises them)


def denoise(
    color,
    *,
    albedo=None,
    normal=None,
    depth=None,
    diffuse=None,
    specular=None,
    variances=None,
    model="auto",
    threads=None,
    progress=None,
):
    """Denoise one frame held in numpy arrays; returns the denoised colour, (H, W, 3) float32.

    See ``Denoiser.denoise``; ``model`` and ``threads`` are ``Denoiser``'s. Frames in a loop
    are faster through one ``Denoiser``, which loads the model once.
    """
    return Denoiser(model, threads=threads).denoise(
        color,
        albedo=albedo,
        normal=normal,
        depth=depth,
        diffuse=diffuse,
        specular=specular,
        variances=variances,
        progress=progress,
    )


def denoise_file(
    input,
    output,
    *,
    model="auto",
    aovs=False,
    layer=None,
    view_layer=None,
    separate=False,
    in_place=False,
    layout=None,
    compression=None,
    no_clobber=False,
    max_memory=None,
    threads=None,
    progress=None,
):
    """Denoise a layered EXR into ``output`` as ``kpcn denoise INPUT -o OUTPUT`` does.

    See ``Denoiser.denoise_file``; ``model``, ``max_memory`` and ``threads`` are ``Denoiser``'s.
    """
    return Denoiser(model, threads=threads, max_memory=max_memory).denoise_file(
        input,
        output,
        aovs=aovs,
        layer=layer,
        view_layer=view_layer,
        separate=separate,
        in_place=in_place,
        layout=layout,
        compression=compression,
        no_clobber=no_clobber,
        progress=progress,
    )


__all__ = ["Denoiser", "Error", "InputError", "IoError", "denoise", "denoise_file", "__version__"]
