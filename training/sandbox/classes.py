"""Classes in user code at run time: the ``type`` and ``__build_class__`` the restricted
builtins hand out (:func:`training.sandbox.guard.restricted_builtins`).

The static check refuses metaclasses, class keywords, special methods that change lookups and
``type(name, bases, dict)`` where it can see them; these refuse the same at run time, however
the code got there (``t = type; t("C", (), d)``, ``type(type(x))``, a base computed at run
time). Without a metaclass or such a special method, a ``match`` class pattern reads only the
public attributes of instances of the class, as ``a.b`` would. Not the boundary (the OS layers
are); the messages say what is refused.
"""

from __future__ import annotations

import builtins
from typing import Any

from training.sandbox.policy import (
    ALLOWED_DUNDER_METHODS,
    NO_METACLASS,
    NO_TYPE_CALL,
    is_dunder,
    special_method_refused,
)

_real_type = builtins.type
_real_build_class = builtins.__build_class__

#: Entries Python itself puts in a class's namespace.
IMPLICIT_CLASS_ENTRIES: frozenset[str] = frozenset(
    {
        "__module__",
        "__qualname__",
        "__doc__",
        "__dict__",
        "__weakref__",
        "__annotations__",
        "__annotate__",
        "__firstlineno__",
        "__static_attributes__",
        "__orig_bases__",
        "__parameters__",
    }
)


def is_metaclass(value: object) -> bool:
    """A class whose instances are classes (``type`` itself, ABCMeta, ...)."""
    return isinstance(value, _real_type) and issubclass(value, _real_type)


class _TypeMeta(_real_type):
    """Makes ``isinstance(x, type)`` and ``issubclass(c, type)`` answer as for the real one."""

    def __instancecheck__(cls, obj: object) -> bool:
        return isinstance(obj, _real_type)

    def __subclasscheck__(cls, sub: Any) -> bool:
        return sub is cls or (isinstance(sub, _real_type) and issubclass(sub, _real_type))

    def __repr__(cls) -> str:
        return "<class 'type'>"


class GuardedType(metaclass=_TypeMeta):
    """``type`` for user code: ``type(x)`` is the type of ``x`` (a metaclass comes back as this
    guarded ``type``, never the real one); ``type(name, bases, dict)`` is refused."""

    def __new__(cls, *args: object, **kwargs: object) -> Any:
        if len(args) != 1 or kwargs:
            raise TypeError(NO_TYPE_CALL)
        found = _real_type(args[0])
        return GuardedType if is_metaclass(found) else found


GuardedType.__name__ = GuardedType.__qualname__ = "type"


def guarded_build_class(func: Any, name: str, /, *bases: Any, **kwds: Any) -> Any:
    """``__build_class__`` for a class statement in user code: no class keywords
    (``metaclass=``), no metaclass or guarded ``type`` as a base, and no special method
    outside :data:`~training.sandbox.policy.ALLOWED_DUNDER_METHODS` in the class body."""
    if kwds:
        shown = ", ".join(f"{k}=" for k in kwds)
        raise TypeError(
            f"class {name}: class keywords ({shown}) are not allowed: a reward function's "
            "classes take no metaclass or class arguments"
        )
    for base in bases:
        if base is GuardedType or is_metaclass(base):
            raise TypeError(f"class {name}: {NO_METACLASS}")
    cls = _real_build_class(func, name, *bases)
    for key in vars(cls):
        if (
            isinstance(key, str)
            and is_dunder(key)
            and key not in ALLOWED_DUNDER_METHODS
            and key not in IMPLICIT_CLASS_ENTRIES
        ):
            raise TypeError(f"class {name}: {special_method_refused(key)}")
    return cls
