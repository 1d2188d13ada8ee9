"""What user reward code may import and touch: one list for the static check and the runtime
guard alike (DeepRacer's allow-list plus the names its validator refuses)."""

from __future__ import annotations

#: Top-level modules a reward function may import [DeepRacer ALLOWLIST_IMPORTS].
ALLOWED_MODULES: frozenset[str] = frozenset({"math", "random", "numpy", "scipy", "shapely"})

#: Submodules of allowed packages that reach files, processes or raw memory.
REFUSED_SUBMODULES: frozenset[str] = frozenset(
    {
        "numpy.ctypeslib",
        "numpy.f2py",
        "numpy.distutils",
        "numpy.testing",
        "numpy.lib.npyio",
        "numpy.lib.format",
        "numpy.rec",
        "scipy.io",
        "scipy.datasets",
        "scipy.misc",
    }
)

#: Built-in names a reward function may not use at all [DeepRacer: open, eval, input, exec,
#: compile, __import__] plus the ones that reach the interpreter's internals.
FORBIDDEN_NAMES: frozenset[str] = frozenset(
    {
        "open",
        "eval",
        "exec",
        "compile",
        "input",
        "__import__",
        "breakpoint",
        "globals",
        "locals",
        "vars",
        "exit",
        "quit",
        "help",
        "memoryview",
        "__builtins__",
        "__loader__",
        "__spec__",
    }
)

#: Attribute names refused anywhere (``np.load``, ``arr.tofile``, ``scipy.io``, ...)
#: [DeepRacer: load, fromfile, genfromtxt, loadtxt, tofile, savez, save, savetxt, memmap].
FORBIDDEN_ATTRIBUTES: frozenset[str] = frozenset(
    {
        "load",
        "loads",
        "save",
        "savez",
        "savez_compressed",
        "savetxt",
        "loadtxt",
        "genfromtxt",
        "fromfile",
        "fromregex",
        "tofile",
        "dump",
        "memmap",
        "open_memmap",
        "DataSource",
        "ctypeslib",
        "ctypes",
        "f2py",
        "distutils",
        "testing",
        "npyio",
        "io",
        "os",
        "sys",
        "subprocess",
        "system",
        "popen",
        "open",
        "builtins",
        # frames, code and tracebacks lead to other modules' globals
        "gi_frame",
        "gi_code",
        "gi_yieldfrom",
        "cr_frame",
        "cr_code",
        "cr_await",
        "ag_frame",
        "ag_code",
        "f_back",
        "f_globals",
        "f_locals",
        "f_builtins",
        "f_code",
        "tb_frame",
        "tb_next",
        "co_code",
        "with_traceback",
        # attribute access by name, in functions that outlive the getattr guard
        "attrgetter",
        "methodcaller",
    }
)

#: Builtins that take an attribute name as their second argument (checked like ``a.name``).
ATTRIBUTE_FUNCTIONS: frozenset[str] = frozenset({"getattr", "setattr", "delattr", "hasattr"})

#: Dunder names a reward function may read as plain names.
ALLOWED_DUNDER_NAMES: frozenset[str] = frozenset({"__name__", "__doc__", "__file__"})

#: Special methods a reward function's classes may define: construction, printing,
#: comparisons, arithmetic, the container, iterator, call and context protocols. The others
#: change how Python itself looks things up (``__getattr__``, ``__instancecheck__``,
#: ``__init_subclass__``, ``__set_name__``, ``__class_getitem__``, ``__match_args__``...): with
#: a ``match`` class pattern they read any attribute of any object, so they are refused.
ALLOWED_DUNDER_METHODS: frozenset[str] = frozenset(
    {
        "__init__", "__repr__", "__str__", "__format__", "__hash__", "__bool__", "__call__",
        "__eq__", "__ne__", "__lt__", "__le__", "__gt__", "__ge__",
        "__len__", "__getitem__", "__setitem__", "__delitem__", "__contains__",
        "__iter__", "__next__", "__reversed__", "__enter__", "__exit__",
        "__neg__", "__pos__", "__abs__", "__invert__", "__round__", "__trunc__", "__floor__",
        "__ceil__", "__int__", "__float__", "__complex__", "__index__",
        *(
            f"__{prefix}{op}__"
            for op in ("add", "sub", "mul", "matmul", "truediv", "floordiv", "mod", "divmod",
                       "pow", "lshift", "rshift", "and", "xor", "or")
            for prefix in ("", "r", "i")
            if not (prefix == "i" and op == "divmod")
        ),
    }
)  # fmt: skip

NO_METACLASS = (
    "a class may not derive from 'type': metaclasses are not allowed in a reward function"
)
NO_TYPE_CALL = (
    "type() with three arguments (a class made at run time) is not allowed; "
    "type(x) gives the type of x, and a class statement makes a class"
)


def special_method_refused(name: str) -> str:
    """The message for defining special method ``name`` outside the allowed ones."""
    return (
        f"defining '{name}' is not allowed: a reward function's classes may define only "
        "ordinary special methods (__init__, __repr__, __eq__, __add__, __len__, __iter__, "
        "__call__, ...), none that change how Python looks names up"
    )


#: Star imports are refused except from these (numpy's namespace holds load/save/...).
STAR_IMPORT_MODULES: frozenset[str] = frozenset({"math", "random"})


def is_dunder(name: str) -> bool:
    return len(name) > 4 and name.startswith("__") and name.endswith("__")


def attribute_refused(name: str) -> bool:
    """True for attribute names user code may not touch: private/dunder or file/OS related."""
    return name.startswith("_") or name in FORBIDDEN_ATTRIBUTES


def module_refused(name: str) -> bool:
    """True unless ``name`` is an allowed module or a public, harmless submodule of one."""
    parts = name.split(".")
    if parts[0] not in ALLOWED_MODULES:
        return True
    if any(part.startswith("_") for part in parts[1:]):
        return True
    return any(name == bad or name.startswith(bad + ".") for bad in REFUSED_SUBMODULES)
