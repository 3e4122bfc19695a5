"""XLA compiler options for this package's compiled programs on the CPU.

Two kinds of program, two sets of options. Each set applies only to the programs compiled
with it, never to the user's own JAX code. The options are probed once: one this XLA does not
know (or any, on a backend that is not the CPU) is left out, and JAX's default applies.

* **The DE's loop** runs thousands of times, so it is compiled for speed. XLA's CPU backend
  hands some fused reductions to YNNPACK; for the objectives here (a few hundred float64
  operations per member, reduced over a handful of landmarks) that is slower than XLA's own
  loops, because it stores every intermediate array of the reduction and reads it back.
  Turning it off made a DE generation at N = 10,000 about 1.4× faster on the 2-core CPU this
  was tuned on (``benchmarks/de_throughput.py`` measures it).
* **Everything else** (the LM polish, the DE's initial population, the diagnostics' batched
  Jacobians, the stage reports) runs a handful of times per calibration, so its compile time
  is what a user waits for. These are compiled with XLA's classic loop emitters and without
  LLVM's optimisation passes (level 0), or at level 1 for a program called once per
  iteration of a host loop. On the diagnostics' stage-1 Jacobians, compilation takes 0.94 s
  at full optimisation, 0.59 s at level 1 and 0.30 s at level 0, and a call 0.57, 0.58 and
  1.39 ms. ``benchmarks/startup.py`` measures what a first calibration from the shell spends
  compiling, program by program.

One more setting cannot be scoped to a program: LLVM's loop vectoriser leaves any loop of
fewer than 16 iterations scalar, and XLA's CPU code for a population is full of them (the 12
parameters of a member, the 9 landmarks). :func:`vectorise_small_loops` lowers that limit to
4 for the whole process, through ``XLA_FLAGS``, so it must run before JAX's first computation.
The command line, the benchmarks and the notebooks call it; a library user may call it
first thing. It changes which loops use SIMD instructions, not the arithmetic: the DE's
populations are bit-identical with and without it (``tests/test_de.py``). On the 2-core
machine it made a DE generation at N = 10,000 about 1.3× faster (``benchmarks/RESULTS.md``).
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.metadata
import inspect
import json
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import numpy as np

_NO_YNN_FUSION: dict[str, Any] = {"xla_cpu_experimental_ynn_fusion_type": ""}
_CLASSIC_EMITTERS: dict[str, Any] = {"xla_cpu_use_fusion_emitters": False}
_LLVM_OPT_LEVEL = "xla_backend_optimization_level"
SMALL_LOOPS_FLAG = "--xla_backend_extra_options=-vectorizer-min-trip-count=4"


def _accepts(options: dict[str, Any]) -> bool:
    try:
        jax.jit(lambda x: x + 1, compiler_options=options).lower(1.0).compile()
    except Exception:  # an XLA without an option rejects it by name
        return False
    return True


@functools.cache
def _supported() -> frozenset[str]:
    """The options this XLA accepts: one small compilation, unless some are rejected."""
    if jax.default_backend() != "cpu":
        return frozenset()
    every = {**_NO_YNN_FUSION, **_CLASSIC_EMITTERS, _LLVM_OPT_LEVEL: 0}
    if _accepts(every):
        return frozenset(every)
    return frozenset(k for k, v in every.items() if _accepts({k: v}))


def _keep(options: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in options.items() if k in _supported()}


def loop_compiler_options() -> dict[str, Any]:
    """Options for a hot loop (the DE's generations): those this XLA has."""
    return _keep(_NO_YNN_FUSION)


def fast_compile_options(llvm_opt_level: int = 0) -> dict[str, Any]:
    """Options for a program run a few times per calibration: those this XLA has.

    Args:
        llvm_opt_level: LLVM's optimisation level, 0–3. 0 compiles fastest; a program called
            hundreds of times (the diagnostics' batched Jacobians, once per LM iteration) is
            better off at 1, which runs it about 2.4× faster for about 0.3 s more compilation.
    """
    return _keep({**_CLASSIC_EMITTERS, _LLVM_OPT_LEVEL: llvm_opt_level})


def _built_at_first_call(fn: Callable, options: Callable[[], dict], jit: Callable, jit_kwargs):
    # JAX chooses its backend at the first computation, and the options are probed against
    # it, so the jitted function is built then, once, and reused afterwards.
    @functools.cache
    def jitted():
        return jit(fn, compiler_options=options(), **jit_kwargs)

    name = f"{fn.__module__}.{fn.__qualname__}"

    @functools.wraps(fn)
    def call(*args, **kwargs):
        folder = _store.folder
        if folder is None or jit_kwargs:
            return jitted()(*args, **kwargs)
        call_, dynamic = _signature(name, args, kwargs, jit is eqx.filter_jit, options())
        if call_ is None:  # an argument without a stable description: not stored
            return jitted()(*args, **kwargs)
        programs = _store.programs
        if call_.key not in programs:
            programs[call_.key] = _load(folder, call_) or _build(folder, call_, fn)
        program = programs[call_.key]
        if program is None:  # this program cannot be exported (e.g. a host callback)
            return jitted()(*args, **kwargs)
        return program(*dynamic)

    return call


def hot_loop(fn: Callable) -> Callable:
    """``eqx.filter_jit(fn)`` with :func:`loop_compiler_options`."""
    return _built_at_first_call(fn, loop_compiler_options, eqx.filter_jit, {})


def fast_compile(
    fn: Callable | None = None,
    *,
    jit: Callable = eqx.filter_jit,
    llvm_opt_level: int = 0,
    **jit_kwargs,
):
    """Decorator: ``jit(fn, **jit_kwargs)`` with :func:`fast_compile_options`."""
    if fn is None:
        return functools.partial(fast_compile, jit=jit, llvm_opt_level=llvm_opt_level, **jit_kwargs)
    return _built_at_first_call(
        fn, functools.partial(fast_compile_options, llvm_opt_level), jit, jit_kwargs
    )


def vectorise_small_loops() -> bool:
    """Let LLVM vectorise loops of 4 or more iterations in every program this process compiles.

    Adds :data:`SMALL_LOOPS_FLAG` to ``XLA_FLAGS``. It applies only if JAX has not yet started
    a backend (XLA reads its flags once, then) and ``XLA_FLAGS`` does not already set
    ``xla_backend_extra_options`` (the user's own choice is kept) nor name a flag file (XLA
    reads a value that does not start with ``--`` as a file name). Returns whether it applied.
    """
    flags = os.environ.get("XLA_FLAGS", "").strip()
    if flags and not flags.startswith("--"):
        return False
    if "xla_backend_extra_options" in flags or _backend_started():
        return False
    os.environ["XLA_FLAGS"] = f"{flags} {SMALL_LOOPS_FLAG}".strip()
    return True


def _backend_started() -> bool:
    try:
        from jax._src import xla_bridge
    except ImportError:  # a JAX that moved it: assume started, and change nothing
        return True
    started = getattr(xla_bridge, "backends_are_initialized", None)
    return True if started is None else bool(started())


# -- serialized programs -------------------------------------------------------------------
#
# A warm run of the command line used to trace and lower every program again (seconds of
# Python) only to find XLA's compiled code in the persistent cache. With a folder set
# (store_programs), each program of fast_compile and hot_loop is also kept as jax.export's
# serialized StableHLO, under a key that names everything the program depends on: the
# function, this package's source, the arguments' structure, static values, shapes and
# dtypes, the compiler options, the JAX version, x64 and the backend. A later process loads
# it instead of tracing, and XLA's cache supplies the compiled code. A file that cannot be
# read back (truncated, another JAX) is rebuilt; an argument that has no exact description
# (an object whose repr shows an address or elides numbers) is not stored at all.

FORMAT = b"handeye-jax.program/1\n"


class _Store:
    def __init__(self):
        self.folder: Path | None = None
        self.announce: Callable[[str], None] | None = None
        self.programs: dict[str, Callable | None] = {}  # loaded or built, by key
        self.calls: dict[tuple, _Call | None] = {}  # described calls, by signature


_store = _Store()


def store_programs(
    folder: str | os.PathLike | None, announce: Callable[[str], None] | None = None
) -> None:
    """Keep this package's compiled programs serialized (``jax.export``) in ``folder``, so a
    later process neither traces nor lowers them; ``None`` turns it off (the default).

    Pair it with JAX's persistent compilation cache (``jax_compilation_cache_dir``), which
    keeps the compiled code: the command line puts this folder inside that one.

    Called again with the folder it already uses, it keeps the programs this process has
    loaded or built (each command run in one process calls it; reloading every program cost
    a warm in-process ``calibrate`` about 3 of its 4.5 s). Another folder, or ``None``, drops
    them.

    Args:
        folder: where the programs are kept (created when the first is stored).
        announce: called with a program's name before it is built (traced, exported and
            compiled), which takes a second or so each on a first run; e.g. to say so.
    """
    folder = None if folder is None else Path(folder)
    _store.announce = announce
    if folder is not None and folder == _store.folder:
        return
    _store.folder = folder
    _store.programs = {}
    _store.calls = {}


#: The libraries whose code a traced program holds besides this package's own.
_TRACED_LIBRARIES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "numpy")


@functools.cache
def _source_digest() -> str:
    """SHA-256 of this package's source and its libraries' versions: any change of the code
    makes new programs."""
    root = Path(__file__).resolve().parents[1]  # the whole package, not this folder
    h = hashlib.sha256()
    for name in _TRACED_LIBRARIES:
        try:
            h.update(f"{name} {importlib.metadata.version(name)}\0".encode())
        except importlib.metadata.PackageNotFoundError:
            h.update(f"{name} -\0".encode())
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


_SAFE_STATIC = (type(None), bool, int, float, complex, str, bytes)
# A description that shows an address, an elided array or NumPy's rounded printout does not
# say exactly what the program was built for.
_UNSTABLE = re.compile(r" at 0x|\.\.\.|array\(|<locals>|<lambda>")


def _describe(treedef) -> str:
    """A pytree structure with each node's type by its full name (JAX's own printout names a
    class without its module) and its data."""
    node = treedef.node_data()
    if node is None:
        return "*"
    cls, aux = node
    name = f"{cls.__module__}.{cls.__qualname__}"
    children = ",".join(_describe(c) for c in treedef.children())
    return f"{name}[{aux!r}]({children})"


def _static_repr(x: Any) -> str | None:
    if isinstance(x, _SAFE_STATIC) or isinstance(x, np.generic) and x.ndim == 0:
        return repr(x)
    if isinstance(x, type) or inspect.isfunction(x):
        return f"{x.__module__}.{x.__qualname__}"
    return None


@dataclass
class _Call:
    """A stored program's signature: its key, options, argument shapes and how to rebuild
    its arguments from the traced arrays (the rest of them fixed, as in ``jit``)."""

    key: str
    name: str
    description: str
    options: dict[str, Any]
    specs: list[jax.ShapeDtypeStruct]
    treedef: Any
    positions: list[int]  # where the traced arrays go among the leaves
    template: list[Any]  # the leaves, the static ones in place

    def rebuild(self, dynamic: list[Any]) -> tuple[tuple, dict]:
        leaves = list(self.template)
        for i, x in zip(self.positions, dynamic, strict=True):
            leaves[i] = x
        return jax.tree.unflatten(self.treedef, leaves)

    @classmethod
    def of(cls, name, treedef, leaves, positions, options) -> _Call | None:
        positions_set = set(positions)
        statics = [_static_repr(x) for i, x in enumerate(leaves) if i not in positions_set]
        if any(r is None for r in statics):
            return None
        try:
            avals = [jax.typeof(leaves[i]) for i in positions]
        except TypeError:
            return None
        description = repr((
            name, _describe(treedef), positions, statics,
            [(a.shape, str(a.dtype), a.weak_type) for a in avals], sorted(options.items()),
            jax.__version__, jax.config.jax_enable_x64, jax.default_backend(), _source_digest(),
        ))  # fmt: skip
        if _UNSTABLE.search(description):
            return None
        specs = [jax.ShapeDtypeStruct(a.shape, a.dtype, weak_type=a.weak_type) for a in avals]
        template = [None if i in positions_set else x for i, x in enumerate(leaves)]
        key = hashlib.sha256(description.encode()).hexdigest()
        return cls(key, name, description, options, specs, treedef, positions, template)


def _leaf_signature(x: Any) -> tuple:
    try:
        return (x.shape, x.dtype, getattr(x, "weak_type", False))
    except AttributeError:  # a Python scalar, traced by jax.jit
        return (type(x),)


def _signature(name: str, args, kwargs, filtered: bool, options: dict):
    """The call's ``_Call`` (``None`` if it cannot be stored) and its traced arrays.

    Describing a call exactly takes about a millisecond of Python; calls of the same shapes
    and static values share one, looked up by a signature that takes microseconds (a
    program of the LM's batches is called hundreds of times per calibration)."""
    leaves, treedef = jax.tree.flatten((args, kwargs))
    if filtered:  # eqx.filter_jit: arrays are traced, everything else is static
        positions = [i for i, x in enumerate(leaves) if eqx.is_array(x)]
    else:  # jax.jit: every leaf is traced
        positions = list(range(len(leaves)))
    dynamic = [leaves[i] for i in positions]
    traced = set(positions)
    # By type and, for floats, repr too: 1, 1.0 and True are equal, and so are 0.0 and -0.0.
    statics = tuple(
        (type(x), repr(x) if isinstance(x, float | complex) else x)
        for i, x in enumerate(leaves) if i not in traced
    )  # fmt: skip
    signature = (name, treedef, str(treedef), tuple(positions), statics,
                 tuple(_leaf_signature(x) for x in dynamic), tuple(sorted(options.items())),
                 jax.config.jax_enable_x64)  # fmt: skip
    try:
        return _store.calls[signature], dynamic
    except KeyError:
        pass
    except TypeError:  # an unhashable static value: described afresh
        return _Call.of(name, treedef, leaves, positions, options), dynamic
    call = _store.calls[signature] = _Call.of(name, treedef, leaves, positions, options)
    return call, dynamic


class _Probe(eqx.Module):
    x: Any


# What a Module without static fields carries through JAX's flattening: all a result of that
# kind needs to be serialized (jax.export serializes only the pytree nodes it is told about).
_PLAIN_MODULE_AUX = jax.tree.structure(_Probe(0)).node_data()[1]
_registered: set[type] = set()


def _register(cls: type) -> None:
    if cls not in _registered:
        jax.export.register_pytree_node_serialization(
            cls, serialized_name=f"{cls.__module__}.{cls.__qualname__}",
            serialize_auxdata=lambda aux: b"",
            deserialize_auxdata=lambda data: _PLAIN_MODULE_AUX,
        )  # fmt: skip
        _registered.add(cls)


def _result_classes(treedef) -> list[type] | None:
    """The Module classes in a result's structure, if each is one jax.export can be told
    about (no static fields); ``None`` otherwise."""
    found: list[type] = []
    node = treedef.node_data()
    if node is not None and node[0] not in (tuple, list, dict, type(None)):
        cls, aux = node
        if not (isinstance(cls, type) and issubclass(cls, eqx.Module)) or aux != _PLAIN_MODULE_AUX:
            return None
        if "<locals>" in cls.__qualname__:
            return None
        found.append(cls)
    for child in treedef.children():
        more = _result_classes(child)
        if more is None:
            return None
        found.extend(more)
    return found


def _class_at(path: str) -> type | None:
    module, _, qualname = path.partition(":")
    if not module.startswith(f"{__name__.split('.')[0]}."):  # this package's own result types
        return None
    obj: Any = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj if isinstance(obj, type) and issubclass(obj, eqx.Module) else None


def _path(folder: Path, call: _Call) -> Path:
    return folder / f"{call.key}.program"


def _named(f: Callable, call: _Call) -> Callable:
    f.__name__ = f.__qualname__ = call.name.rsplit(".", 1)[-1]  # as JAX's compile log names it
    return f


def _runner(exported, call: _Call) -> Callable:
    run = _named(lambda *a: exported.call(*a), call)
    return jax.jit(run, compiler_options=call.options or None)


def _load(folder: Path, call: _Call) -> Callable | None:
    """The stored program of ``call``, ready to run; ``None`` if there is none that reads."""
    try:
        data = _path(folder, call).read_bytes()
    except OSError:
        return None
    try:
        if not data.startswith(FORMAT):
            return None
        header, _, blob = data[len(FORMAT) :].partition(b"\n")
        meta = json.loads(header)
        if meta["description"] != call.description:
            return None
        if meta["sha256"] != hashlib.sha256(blob).hexdigest():  # truncated or damaged
            return None
        for path in meta["classes"]:
            cls = _class_at(path)
            if cls is None:
                return None
            _register(cls)
        exported = jax.export.deserialize(bytearray(blob))
        if [(a.shape, a.dtype) for a in exported.in_avals] != [
            (s.shape, s.dtype) for s in call.specs
        ]:
            return None
    except Exception:  # truncated, or written by another JAX: rebuilt by the caller
        return None
    return _runner(exported, call)


#: Custom-call targets met in this process's programs (LAPACK's): allowed from the first try.
_unstable_targets: set[str] = set()


def _custom_calls(lowered_text: str) -> set[str]:
    return set(re.findall(r"custom_call @([\w.$-]+)", lowered_text)) | set(
        re.findall(r'call_target_name = "([^"]+)"', lowered_text)
    )


def _build(folder: Path, call: _Call, fn: Callable) -> Callable | None:
    """Export ``fn`` for ``call``, store it, and return it ready to run (``None`` if it
    cannot be exported or serialized: then it is jitted as usual)."""

    if _store.announce is not None:
        _store.announce(call.name)

    def flat(*dynamic):
        a, k = call.rebuild(list(dynamic))
        return fn(*a, **k)

    jitted = jax.jit(_named(flat, call))

    def export(targets):
        checks = [jax.export.DisabledSafetyCheck.custom_call(t) for t in sorted(targets)]
        return jax.export.export(jitted, disabled_checks=checks)(*call.specs)

    try:
        try:
            exported = export(_unstable_targets)
        except ValueError:
            # LAPACK's solvers are custom calls JAX does not promise to keep across versions;
            # the key holds the JAX version, so a stored program never meets another one. A
            # Python callback is another custom call, and one that cannot be stored.
            targets = _custom_calls(jitted.lower(*call.specs).as_text())
            if any("callback" in t for t in targets):
                return None
            _unstable_targets.update(targets)
            exported = export(_unstable_targets)
        classes = _result_classes(exported.out_tree)
        if classes is None:
            return None
        for cls in classes:
            _register(cls)
        blob = exported.serialize()
    except Exception:  # e.g. a host callback, or no flatbuffers to serialize with
        return None
    meta = {
        "description": call.description,
        "classes": sorted({f"{c.__module__}:{c.__qualname__}" for c in classes}),
        "sha256": hashlib.sha256(blob).hexdigest(),
    }
    data = FORMAT + json.dumps(meta).encode() + b"\n" + bytes(blob)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{call.key}.{os.getpid()}.tmp"
        tmp.write_bytes(data)
        os.replace(tmp, _path(folder, call))  # whole or not at all, for a concurrent run
    except OSError:  # an unwritable folder only costs time
        pass
    # Run what a later process will load, so that both lower to the same module and the
    # compilation cache serves the second run already.
    return _runner(jax.export.deserialize(blob), call)
