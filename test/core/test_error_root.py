"""
One error root: every error class of the package subclasses EmfcError and a builtin.

A node catches :class:`~emfc_ros.core.errors.EmfcError` for everything emfc_ros refuses;
older callers keep catching the builtin (``except ValueError``). Warnings are not errors, and
interrupts (``RunInterrupted``, a ``KeyboardInterrupt``) must stay out of ``except Exception``.
"""

import ast
import importlib
import inspect
from pathlib import Path
import pkgutil
from typing import List

import emfc_ros.cli
import emfc_ros.core
from emfc_ros.core import errors
from emfc_ros.core.errors import EmfcError
import emfc_ros.nodes

#: Classes that are not errors: warnings, and interrupts that ``except Exception`` must miss.
NOT_ERRORS = (Warning, KeyboardInterrupt, SystemExit, GeneratorExit)


def _module_names() -> List[str]:
    names = ['emfc_ros.core', 'emfc_ros.cli', 'emfc_ros.nodes']
    for package in (emfc_ros.core, emfc_ros.cli):
        names += [m.name for m in pkgutil.walk_packages(package.__path__,
                                                        package.__name__ + '.')]
    names += [m.name for m in pkgutil.iter_modules(emfc_ros.nodes.__path__, 'emfc_ros.nodes.')]
    return sorted(set(names))


def _exception_classes() -> List[type]:
    """Every BaseException subclass defined (not imported) in a package module."""
    found = []
    for name in _module_names():
        module = importlib.import_module(name)
        found += [cls for cls in vars(module).values()
                  if inspect.isclass(cls) and issubclass(cls, BaseException)
                  and cls.__module__ == module.__name__]
    return found


def _has_builtin(cls: type) -> bool:
    """Whether a builtin exception class other than the two roots is among its bases."""
    return any(b.__module__ == 'builtins' and b not in (Exception, BaseException, object)
               for b in cls.__mro__)


def _offenders(classes: List[type]) -> List[str]:
    return [f'{cls.__module__}.{cls.__qualname__} '
            f'(bases {", ".join(b.__qualname__ for b in cls.__bases__)})'
            for cls in classes
            if cls is not EmfcError and not issubclass(cls, NOT_ERRORS)
            and not (issubclass(cls, EmfcError) and _has_builtin(cls))]


def test_every_error_class_subclasses_the_root_and_a_builtin():
    classes = _exception_classes()
    assert len(classes) >= 10, [c.__qualname__ for c in classes]
    offenders = _offenders(classes)
    assert offenders == [], ('not an EmfcError beside a builtin (e.g. class FooError('
                             'EmfcError, ValueError)): ' + '; '.join(offenders))


def test_the_check_itself_finds_an_error_without_the_root_or_a_builtin():
    class FooError(ValueError):
        pass

    class BareError(EmfcError):
        pass

    class GoodError(EmfcError, OSError):
        pass

    class OddWarning(UserWarning):
        pass

    found = _offenders([FooError, BareError, GoodError, OddWarning])
    assert [f.split(' ')[0].rsplit('.', 1)[-1] for f in found] == ['FooError', 'BareError']


def test_the_builtins_still_catch_them():
    from emfc_ros.core.bag.errors import BagExistsError
    from emfc_ros.core.device.errors import DeviceTimeoutError
    from emfc_ros.core.errors import ConfigError

    assert issubclass(ConfigError, ValueError)
    assert issubclass(BagExistsError, FileExistsError)
    assert issubclass(DeviceTimeoutError, TimeoutError) and issubclass(DeviceTimeoutError, OSError)
    assert issubclass(DeviceTimeoutError, EmfcError)
    assert emfc_ros.core.EmfcError is EmfcError
    assert str(ConfigError('a.b', 'must be positive')) == 'a.b: must be positive'


def test_ctrl_c_is_no_error():
    from emfc_ros.cli.experiment import RunInterrupted

    assert issubclass(RunInterrupted, KeyboardInterrupt)
    assert not issubclass(RunInterrupted, Exception)


def test_the_root_module_imports_nothing_of_the_package():
    tree = ast.parse(Path(errors.__file__).read_text())
    imports = [node for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))]
    assert imports == []
