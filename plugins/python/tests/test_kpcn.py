"""The `kpcn` Python module against the `kpcn` command on the same files (plugins/python/test.sh
runs this in a fresh virtual environment holding only the built wheel and the test tools)."""

import os
import pathlib
import signal
import subprocess
import sys
import textwrap
import threading
import ast
import inspect
import time
import warnings

import numpy as np
import OpenEXR
import pytest

import kpcn

ROOT = pathlib.Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "examples/data/spheres-crop-00016spp.exr"
KPCN = os.environ.get("KPCN_BIN", str(ROOT / "target/debug/kpcn"))
MEANS = ["RGB", "diffuse", "specular", "albedo", "normal", "depth.Z"]
VARIANCES = ["colorVariance.Z", "diffuseVariance.Z", "specularVariance.Z", "albedoVariance.Z", "normalVariance.Z", "depthVariance.Z"]


def channels(path):
    """Every channel of an EXR as numpy arrays (R/G/B groups as (H, W, 3))."""
    with OpenEXR.File(str(path)) as f:
        return {name: c.pixels.copy() for name, c in f.channels().items()}


def cli(*args):
    subprocess.run([KPCN, "denoise", "-q", *map(str, args)], check=True)


def write_exr(path, chans):
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, chans).write(str(path))


def arrays(chans):
    """The keyword arguments of `kpcn.denoise` for an EXR's channels."""
    return {
        "diffuse": chans["diffuse"],
        "specular": chans["specular"],
        "albedo": chans["albedo"],
        "normal": chans["normal"],
        "depth": chans["depth.Z"],
    }


def same_bits(a, b):
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a.view(np.uint32), b.view(np.uint32))


@pytest.fixture(scope="module")
def example():
    return channels(EXAMPLE)


@pytest.fixture(scope="module")
def denoiser():
    return kpcn.Denoiser()


def test_denoise_file_writes_what_the_cli_writes(tmp_path):
    cli(EXAMPLE, "-o", tmp_path / "cli.exr")
    report = kpcn.denoise_file(EXAMPLE, tmp_path / "py.exr")
    assert [r["layer"] for r in report] == ["denoised"] and report[0]["width"] == 160
    ours, theirs = channels(tmp_path / "py.exr"), channels(tmp_path / "cli.exr")
    assert ours.keys() == theirs.keys() and "denoised" in ours
    for name in ours:
        assert np.array_equal(ours[name].view(np.uint16 if ours[name].dtype == np.float16 else np.uint32),
                              theirs[name].view(np.uint16 if theirs[name].dtype == np.float16 else np.uint32)), name


@pytest.mark.parametrize("with_variances", [False, True])
def test_arrays_denoise_as_the_cli_does_the_same_passes(tmp_path, example, denoiser, with_variances):
    keep = MEANS + (VARIANCES if with_variances else [])
    write_exr(tmp_path / "passes.exr", {k: example[k] for k in keep})
    cli(tmp_path / "passes.exr", "--separate", "-o", tmp_path / "cli.exr")
    expected = channels(tmp_path / "cli.exr")["denoised"]
    variances = {k.removesuffix("Variance.Z"): example[k] for k in VARIANCES} if with_variances else None
    # float16 as the file holds them, float32, and strided views of both: one result.
    for convert in (lambda a: a, lambda a: a.astype(np.float32), lambda a: np.ascontiguousarray(a[::-1])[::-1]):
        got = denoiser.denoise(convert(example["RGB"]), **{k: convert(v) for k, v in arrays(example).items()},
                               variances=None if variances is None else {k: convert(v) for k, v in variances.items()})
        assert got.dtype == np.float32 and got.shape == (96, 160, 3)
        assert same_bits(got, expected)


def test_rgba_colour_and_read_only_arrays_are_taken_without_a_copy_of_their_own(example, denoiser):
    rgba = np.concatenate([example["RGB"], np.ones_like(example["RGB"][..., :1])], axis=2).astype(np.float32)
    rgba.setflags(write=False)
    plain = denoiser.denoise(example["RGB"], **arrays(example))
    assert same_bits(denoiser.denoise(rgba, **arrays(example)), plain)


def test_hostile_arrays_give_clear_errors_or_finite_output(example, denoiser):
    a = arrays(example)
    nan = example["RGB"].astype(np.float32)
    nan[10:20, 10:20] = np.nan
    nan[30, 30] = np.inf
    assert np.isfinite(denoiser.denoise(nan, **a)).all()
    with pytest.raises(kpcn.InputError, match="albedo: has 2 channels, needs 3"):
        denoiser.denoise(example["RGB"], **{**a, "albedo": example["albedo"][..., :2]})
    with pytest.raises(kpcn.InputError, match="normal: dtype int64 is not float32 or float16"):
        denoiser.denoise(example["RGB"], **{**a, "normal": np.zeros((96, 160, 3), dtype=np.int64)})
    with pytest.raises(kpcn.InputError, match=r"depth: expected shape \(H, W\) or \(H, W, C\)"):
        denoiser.denoise(example["RGB"], **{**a, "depth": np.zeros(96 * 160, dtype=np.float32)})
    with pytest.raises(ValueError, match="the frame is 160x96"):
        denoiser.denoise(example["RGB"], **{**a, "depth": np.zeros((50, 160), dtype=np.float32)})
    with pytest.raises(kpcn.InputError, match="missing input image albedo"):
        denoiser.denoise(example["RGB"], **{k: v for k, v in a.items() if k != "albedo"})
    with pytest.raises(kpcn.InputError, match="variances: no input `beauty`"):
        denoiser.denoise(example["RGB"], **a, variances={"beauty": example["colorVariance.Z"]})
    with pytest.raises(kpcn.InputError, match="color: expected a numpy array"):
        denoiser.denoise([[1.0]], **a)
    with pytest.raises(kpcn.InputError, match="unknown model `nope`"):
        kpcn.Denoiser("nope")


def test_a_frame_too_large_for_memory_is_an_error_not_an_abort():
    script = textwrap.dedent("""
        import resource, sys
        import numpy as np
        import kpcn
        rgb, z = np.ones((2048, 2048, 3), np.float32), np.ones((2048, 2048), np.float32)
        d = kpcn.Denoiser(threads=1)
        vm = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmSize")) * 1024
        old = resource.getrlimit(resource.RLIMIT_AS)
        resource.setrlimit(resource.RLIMIT_AS, (vm + (256 << 20), old[1]))
        try:
            d.denoise(rgb, diffuse=rgb, albedo=rgb, normal=rgb, depth=z)
            sys.exit("denoised a 4-Mpixel frame in 256 MB")
        except kpcn.Error as e:
            print(e)
        resource.setrlimit(resource.RLIMIT_AS, old)
        small = rgb[:64, :64]
        assert np.isfinite(d.denoise(small, diffuse=small, albedo=small, normal=small, depth=z[:64, :64])).all()
    """)
    o = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert o.returncode == 0, o.stderr
    assert "out of memory" in o.stdout and "max_memory" in o.stdout, o.stdout


def test_file_errors_name_the_file_and_are_python_exceptions(tmp_path):
    with pytest.raises(kpcn.IoError, match="missing.exr: cannot open") as e:
        kpcn.denoise_file(tmp_path / "missing.exr", tmp_path / "out.exr")
    assert isinstance(e.value, OSError) and isinstance(e.value, kpcn.Error)
    with pytest.raises(kpcn.InputError, match="the render would be replaced"):
        kpcn.denoise_file(EXAMPLE, EXAMPLE)
    write_exr(tmp_path / "rgb.exr", {"RGB": np.ones((8, 8, 3), np.float32)})
    with pytest.raises(kpcn.InputError, match="rgb.exr: missing"):
        kpcn.denoise_file(tmp_path / "rgb.exr", tmp_path / "out.exr")
    assert not (tmp_path / "out.exr").exists()


def test_warnings_are_python_warnings(tmp_path, example):
    chans = {k: example[k] for k in MEANS}
    chans["RGB"] = chans["RGB"].copy()
    chans["RGB"][0, 0] = np.nan
    write_exr(tmp_path / "nan.exr", chans)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        kpcn.denoise_file(tmp_path / "nan.exr", tmp_path / "out.exr")
    said = [str(w.message) for w in caught]
    assert any("no variance for" in s for s in said) and any("NaN/Inf samples set to 0" in s for s in said), said


def test_progress_reports_and_cancels(tmp_path, example):
    seen = []
    kpcn.denoise_file(EXAMPLE, tmp_path / "out.exr", progress=seen.append)
    assert seen and seen[-1] == 1.0 and seen == sorted(seen)
    frame = big(example)
    write_exr(tmp_path / "big.exr", {"RGB": frame.pop("color"), **{k if k != "depth" else "depth.Z": v for k, v in frame.items()}})
    one = kpcn.Denoiser(threads=1, max_memory=16)
    with pytest.raises(kpcn.Error, match="big.exr: cancelled"):
        one.denoise_file(tmp_path / "big.exr", tmp_path / "cancelled.exr", progress=lambda f: False)
    assert not (tmp_path / "cancelled.exr").exists()
    with pytest.raises(ZeroDivisionError):
        one.denoise_file(tmp_path / "big.exr", tmp_path / "cancelled.exr", progress=lambda f: 1 / 0)
    assert not (tmp_path / "cancelled.exr").exists()


def big(example, reps=6):
    """The example tiled to a frame big enough to take a while on one thread."""
    return {k: np.tile(v, (reps, reps) + (1,) * (v.ndim - 2)) for k, v in {"color": example["RGB"], **arrays(example)}.items()}


def test_threads_denoise_concurrently_with_the_gil_released(example, denoiser):
    expected = denoiser.denoise(example["RGB"], **arrays(example))
    results, ticks = [None] * 4, []
    stop = threading.Event()

    def tick():
        while not stop.is_set():
            ticks.append(1)
            time.sleep(0.001)

    def work(i):
        results[i] = denoiser.denoise(example["RGB"], **arrays(example))

    ticker = threading.Thread(target=tick)
    ticker.start()
    workers = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    stop.set()
    ticker.join()
    assert all(same_bits(r, expected) for r in results)
    assert len(ticks) > 10, "Python threads ran while kpcn denoised"


def test_arrays_stream_in_bands_with_the_same_bits(example):
    frame = big(example, reps=4)
    in_bands = kpcn.Denoiser(max_memory=16).denoise(**frame)
    whole = kpcn.Denoiser(max_memory=8192).denoise(**frame)
    assert same_bits(in_bands, whole)


@pytest.fixture
def ctrl_c_raises():
    """Python's own Ctrl-C handler for a test, even where the suite runs as a background job
    (its shell leaves SIGINT ignored, and Python then installs none); restored after."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_ctrl_c_cancels_within_a_tile(example, ctrl_c_raises):
    one = kpcn.Denoiser(threads=1, max_memory=16)
    frame = big(example)
    # The fastest of two runs (the first pays for warm-up), and the signal early in the
    # third, so that a busy machine whose first run was slow cannot see the third finish
    # before the signal comes.
    whole = float("inf")
    for _ in range(2):
        start = time.monotonic()
        one.denoise(**frame)
        whole = min(whole, time.monotonic() - start)
    timer = threading.Timer(whole / 20, lambda: os.kill(os.getpid(), signal.SIGINT))
    start = time.monotonic()
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        one.denoise(**frame)
    assert time.monotonic() - start < whole / 2, f"cancelled after {time.monotonic() - start:.2f} s of {whole:.2f} s"


def test_type_stubs_match_the_module():
    """Every public function's parameters, as the stubs declare them and as the module takes them."""
    package = pathlib.Path(kpcn.__file__).parent
    declared = {}
    for stub, owner in [("__init__.pyi", ""), ("_kpcn.pyi", "")]:
        for node in ast.walk(ast.parse((package / stub).read_text())):
            if isinstance(node, ast.ClassDef):
                for f in node.body:
                    if isinstance(f, ast.FunctionDef):
                        declared[f"{node.name}.{f.name}"] = f.args
            elif isinstance(node, ast.FunctionDef) and node.col_offset == 0:
                declared[node.name] = node.args
    assert (package / "py.typed").exists()
    for name, args in declared.items():
        if name.endswith(".model"):
            continue
        obj = kpcn
        for part in name.split("."):
            obj = getattr(obj, part if part != "__init__" else "__new__")
        names = [a.arg for a in args.posonlyargs + args.args + args.kwonlyargs if a.arg not in ("self", "cls")]
        real = [p for p in inspect.signature(obj).parameters if p not in ("self", "cls", "args", "kwargs")]
        if name != "Denoiser.__init__":
            assert names == real, name
        assert inspect.getdoc(obj) or name == "Denoiser.__init__", f"{name} has no docstring"
