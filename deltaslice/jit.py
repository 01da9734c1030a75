"""numba's ``njit`` for the compiled hot loops (reachability, kinematics kernels, path frames),
with a pass-through fallback so a broken install still runs (correct, slow).

Every kernel is compiled with ``cache=True`` (written beside its module in ``__pycache__``: the
first compile after a fresh install takes seconds, later processes load it, without setting up
numba's compiler: :func:`_cache_first`) and numpy's error model (a division by zero gives inf or
NaN, as the vectorised code it replaces, not an exception).

numba itself is imported when a kernel is first called, not when the modules that define kernels
are: importing it takes a few tenths of a second, which a compile spends while its slicing
workers (which run no kernel) slice. Until then ``njit`` gives a
stand-in (:class:`Deferred`); the first call of any stand-in (or :func:`load`) makes numba's
dispatcher of every kernel defined so far and puts it in place of the stand-in wherever a
``deltaslice`` module holds it, so kernels calling kernels compile against dispatchers, and later
calls from Python go straight to them."""

from __future__ import annotations

import contextlib
import functools
import sys

_PENDING: list = []  # the stand-ins made before numba was imported, in definition order
_NJIT = None  # numba.njit once imported (a pass-through where numba is missing)


def _pass_through(*args, **kwargs):  # pragma: no cover
    if args and callable(args[0]):
        return args[0]
    return lambda f: f


class Deferred:
    """A kernel defined before numba was imported. Calling it, or reading an attribute of
    numba's dispatcher (``signatures``, ...), loads numba (:func:`load`) and goes to the dispatcher;
    ``py_func`` is the Python function."""

    def __init__(self, fn, options: dict):
        self.py_func, self.options, self.dispatcher = fn, options, None
        self.__wrapped__ = fn  # inspect.signature and friends read the Python function
        self.__name__, self.__qualname__, self.__module__, self.__doc__ = (
            fn.__name__, fn.__qualname__, fn.__module__, fn.__doc__)

    def __call__(self, *args, **kwargs):
        if self.dispatcher is None:
            load()
        return self.dispatcher(*args, **kwargs)

    def __getattr__(self, name):
        # only attributes not set in __init__ get here: numba's (signatures, ...) load it; dunder
        # lookups (copy, pickle, inspect) and a half-made instance's own fields must not
        if name.startswith("__") or name in ("py_func", "options", "dispatcher"):
            raise AttributeError(name)
        load()
        return getattr(self.dispatcher, name)

    def __reduce__(self):  # by reference, as numba pickles its dispatchers' functions
        return _kernel, (self.__module__, self.__qualname__)

    def __repr__(self):
        return f"<deferred kernel {self.__module__}.{self.__qualname__}>"


def _kernel(module: str, qualname: str):
    """The kernel ``module.qualname`` (a stand-in or numba's dispatcher), for unpickling."""
    import importlib

    return getattr(importlib.import_module(module), qualname)


def loaded() -> bool:
    """Whether numba has been imported and the kernels made (:func:`load`)."""
    return _NJIT is not None


def load() -> None:
    """Import numba and make every deferred kernel's dispatcher, put in its place in every
    ``deltaslice`` module (kernels are found by name from the kernels that call them). Does
    nothing the second time."""
    global _NJIT
    if _NJIT is not None:
        return
    try:  # numba is a declared dependency
        from numba import njit as numba_njit
    except ImportError:  # pragma: no cover
        _NJIT = _pass_through
    else:
        _NJIT = _cache_first(numba_njit)
    for stand_in in _PENDING:
        stand_in.dispatcher = _NJIT(**stand_in.options)(stand_in.py_func)
    for name, module in list(sys.modules.items()):
        if module is None or not (name == "deltaslice" or name.startswith("deltaslice.")):
            continue
        space = vars(module)
        for key, value in list(space.items()):
            if type(value) is Deferred:
                space[key] = value.dispatcher
    _PENDING.clear()


def _cache_first(numba_njit):
    """``numba_njit`` whose dispatchers load a cached kernel without setting up numba's compiler.

    numba sets up its whole compiler before loading a kernel from its cache (``refresh``: every
    typing and lowering registry, numba.np.*, numba.cpython.*, 0.2-0.3 s of the main process
    while the slicing workers slice), though a cached kernel is machine code that needs only
    numba's runtime (NRT; its first kernel crashes without it) and the symbols numba gives the
    linker (its hash secret is the one the set-up adds: imported here). Here a dispatcher looks
    in its cache first; only a kernel that is not there sets the compiler up (with
    :func:`_cython_blas_alone`) and is compiled as numba does. Where numba's internals are not
    as expected, its own way."""
    try:
        import numba.cpython.hashing  # noqa: F401  (registers the hash secret's symbols)
        from numba.core.caching import Cache
        from numba.core.registry import cpu_target
        from numba.core.runtime import rtsys

        context = cpu_target.target_context
        load_cached = Cache._load_overload
        guard = Cache._guard_against_spurious_io_errors
        rtsys.initialize(context)
        _link_lazily(context.codegen())
    except (ImportError, AttributeError):  # pragma: no cover
        return numba_njit
    refreshed = []

    def load_overload(cache, sig, target_context):
        if target_context is context and not refreshed:
            loaded = None  # where the guard swallows an I/O error (on Windows), as numba's own
            with guard(cache):
                loaded = load_cached(cache, sig, target_context)
            if loaded is not None:
                return loaded
            with _cython_blas_alone():  # numba's BLAS check runs here
                context.refresh()
            refreshed.append(True)
        return Cache.load_overload(cache, sig, target_context)

    def make(**options):
        def decorate(fn):
            dispatcher = numba_njit(**options)(fn)
            cache = getattr(dispatcher, "_cache", None)
            if isinstance(cache, Cache):
                cache.load_overload = functools.partial(load_overload, cache)
            return dispatcher
        return decorate

    return make


def _link_lazily(codegen) -> None:
    """``codegen`` loading a cached kernel's library without parsing its linking module.

    numba caches a kernel as its machine code (an object file) beside the LLVM bitcode of the same
    module, which it parses at every load (to link the kernel into a kernel compiled later that
    calls it) and walks, a Python call per function, for the names the kernel defines (which the
    JIT's symbol lookup needs): a third of a cached kernel's load, a tenth of a second of a
    compile's loads, most of it before the planning workers fork, with the other core idle. Here
    the names come from the object file's symbol table (:func:`_elf_defined_symbols`: the same
    names) and the bitcode is parsed only where a kernel compiled in this process links it. An
    object file other than ELF (macOS, Windows), or numba's internals not as expected: numba's own
    load."""
    import llvmlite.binding as ll

    engine, original = getattr(codegen, "_engine", None), getattr(codegen, "unserialize_library", None)
    base = getattr(codegen, "_library_class", None)
    needed = ("enable_object_caching", "_set_compiled_object", "_finalize_final_module", "_get_module_for_linking",
              "_ensure_finalized")
    if (original is None or base is None or not isinstance(getattr(engine, "_defined_symbols", None), set)
            or not all(hasattr(base, n) for n in needed)):
        return  # another numba: its own load

    class LazyLinkingLibrary(base):
        _shared_bitcode = None

        def _get_module_for_linking(self):
            if self._shared_module is None and self._shared_bitcode is not None:
                self._ensure_finalized()
                self._shared_module = ll.parse_bitcode(self._shared_bitcode)
            return super()._get_module_for_linking()

    def unserialize_library(serialized):
        try:
            name, kind, (obj, bitcode) = serialized
        except (TypeError, ValueError):  # not numba's (name, kind, (object, bitcode)) of an object file
            return original(serialized)
        symbols = _elf_defined_symbols(obj) if kind == "object" else None
        if not symbols:
            return original(serialized)
        library = LazyLinkingLibrary(codegen, name)
        library._shared_bitcode = bitcode
        library.enable_object_caching()
        library._set_compiled_object(obj)
        library._finalize_final_module()
        engine._defined_symbols |= symbols
        return library

    codegen.unserialize_library = unserialize_library


def _elf_defined_symbols(obj) -> set | None:
    """The names of the symbols an ELF64 little-endian object file defines (functions and data,
    not sections or files), or None for anything else (another format, a truncated file)."""
    import struct

    try:
        if bytes(obj[:6]) != b"\x7fELF\x02\x01":
            return None
        shoff = struct.unpack_from("<Q", obj, 0x28)[0]
        shentsize, shnum = struct.unpack_from("<HH", obj, 0x3A)
        sections = [struct.unpack_from("<IIQQQQIIQQ", obj, shoff + i * shentsize) for i in range(shnum)]
        names = set()
        for _name, kind, _flags, _addr, offset, size, link, _info, _align, entsize in sections:
            if kind != 2 or entsize < 24:  # SHT_SYMTAB
                continue
            strings = sections[link][4]
            for k in range(size // entsize):
                st_name, st_info, _other, st_shndx = struct.unpack_from("<IBBH", obj, offset + k * entsize)
                if st_shndx == 0 or (st_info & 0xF) in (3, 4) or st_name == 0:  # undefined, SECTION, FILE
                    continue
                start = strings + st_name
                names.add(bytes(obj[start : obj.index(b"\0", start)]).decode())
        return names
    except (struct.error, ValueError, IndexError, UnicodeDecodeError):
        return None


@contextlib.contextmanager
def _cython_blas_alone():
    """While numba's compiler loads, ``scipy.linalg.cython_blas`` loaded alone, not through its package.

    numba checks for a BLAS as its compiler loads by importing that module, which imports all of
    scipy.linalg first: 0.2-0.4 s of a compile's busiest stretch, most of it scipy's array-API
    layer cloning numpy (numpy.f2py, numpy.testing, ...). The kernels here use no BLAS. The module
    is put in ``sys.modules`` for the check and taken out after: a later import goes through its
    package as usual and gets the same module (an extension module is initialised once a
    process), so numba's BLAS calls, were a kernel to make any, still work. Where scipy is laid out
    otherwise, numba imports the package itself, as before."""
    name = "scipy.linalg.cython_blas"
    module = None
    if "scipy.linalg" not in sys.modules and name not in sys.modules:
        try:
            import importlib.machinery
            import importlib.util
            import os

            import scipy

            finder = importlib.machinery.FileFinder(
                os.path.join(os.path.dirname(scipy.__file__), "linalg"),
                (importlib.machinery.ExtensionFileLoader, importlib.machinery.EXTENSION_SUFFIXES))
            spec = finder.find_spec(name)
            if spec is not None:
                loaded = importlib.util.module_from_spec(spec)
                spec.loader.exec_module(loaded)
                sys.modules[name] = module = loaded
        except Exception:  # numba imports scipy.linalg itself, as it would without this
            module = None
    try:
        yield
    finally:
        if module is not None and sys.modules.get(name) is module and "scipy.linalg" not in sys.modules:
            del sys.modules[name]


def njit(*args, **kwargs):
    """``numba.njit(cache=True, error_model="numpy", **kwargs)``; usable bare (``@njit``) or called.
    Before numba is loaded, a :class:`Deferred` stand-in."""
    kwargs.setdefault("cache", True)
    kwargs.setdefault("error_model", "numpy")

    if args and not callable(args[0]):
        raise TypeError("njit: give options as keywords (the kernels here are typed at their first call)")

    def make(fn):
        if _NJIT is not None:
            return _NJIT(**kwargs)(fn)
        stand_in = Deferred(fn, kwargs)
        _PENDING.append(stand_in)
        return stand_in

    return make(args[0]) if args else make
