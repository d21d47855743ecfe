"""Stand-in for ``launch_ros.actions``: ``Node`` (see the stand-in ``launch`` package)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
import os
from pathlib import Path
import tempfile
from typing import Any, Dict, List, Optional, Tuple

from ament_index_python.packages import get_package_prefix
from launch import (LaunchContext, normalize_to_list_of_substitutions, perform_substitutions,
                    refuse_keywords, refuse_missing, Substitution, SubstitutionFailure,
                    UnsupportedByStub)
from launch_ros.parameter_descriptions import ParameterValue
import yaml

OUTPUTS = ('screen', 'log', 'both', 'own_log')


@dataclass
class NodeProcess:
    """
    What ``ros2 launch`` runs for a ``Node``: the command, the environment, the names.

    Attributes
    ----------
    cmd : list of str
        ``<prefix>/lib/<package>/<executable> [arguments] --ros-args -r __node:=<name>
        -r __ns:=<namespace> --params-file <file> ... -r <from>:=<to> ...``.
    additional_env : dict
        Added to the launch's environment.
    executable, node_name, namespace, output : str
        As expanded.
    parameters : list
        Per entry of ``parameters``: the evaluated dict, or the params-file path.
    """

    cmd: List[str]
    additional_env: Dict[str, str]
    executable: str
    node_name: str
    namespace: str
    output: str
    parameters: List[Any] = field(default_factory=list)


def _normalize_parameter_dict(params: Mapping, prefix: str = '') -> Dict[str, Any]:
    """Flatten nested dicts with '.' and normalize values (``normalize_parameter_dict``)."""
    out: Dict[str, Any] = {}
    for name, value in params.items():
        if not isinstance(name, str):
            raise UnsupportedByStub('parameter names that are substitutions are not '
                                    'implemented by the test stand-in')
        full = f'{prefix}.{name}' if prefix else name
        if isinstance(value, Mapping):
            out.update(_normalize_parameter_dict(value, full))
        elif isinstance(value, str):
            # The real one stores yaml.dump(value) and reads it back with YAML rules.
            out[full] = normalize_to_list_of_substitutions(yaml.dump(value))
        elif isinstance(value, Substitution):
            out[full] = [value]
        elif isinstance(value, (bool, int, float, ParameterValue)):
            out[full] = value
        else:
            raise UnsupportedByStub(f'parameter {full!r}: value {value!r} '
                                    f'({type(value).__name__}) is not implemented by the '
                                    'test stand-in (scalars, substitutions, ParameterValue)')
    return out


def _evaluate_parameter_dict(context: LaunchContext, params: Dict[str, Any]) -> Dict[str, Any]:
    """Evaluate a normalized dict (``launch_ros.utilities.evaluate_parameter_dict``)."""
    out: Dict[str, Any] = {}
    for name, value in params.items():
        if isinstance(value, list):
            text = perform_substitutions(context, value)
            if not text:
                text = "''"
            try:
                loaded = yaml.safe_load(text)
            except yaml.YAMLError:
                raise TypeError(f'Unable to parse the value of parameter {name} as yaml. If the '
                                'parameter is meant to be a string, try wrapping it in '
                                'launch_ros.parameter_descriptions.ParameterValue'
                                '(value, value_type=str)') from None
            if type(loaded) in (bool, int, float, str, bytes):
                out[name] = loaded
            elif isinstance(loaded, list):
                raise UnsupportedByStub(f'parameter {name}: list values are not implemented by '
                                        'the test stand-in')
            else:
                raise TypeError(f'Allowed value types are bytes, bool, int, float, str, '
                                f'Sequence[...]. Got {type(loaded)} for "{name}".')
        elif isinstance(value, ParameterValue):
            out[name] = value.evaluate(context)
        else:
            out[name] = value
    return out


class Node:
    """
    A ROS node process (``launch_ros.actions.Node`` of Jazzy).

    Parameters
    ----------
    executable : str
        Executable in ``<prefix>/lib/<package>``.
    package : str
        The package (required here: a bare executable path is not implemented).
    name, namespace : str or Substitution, optional
        ``-r __node:=<name>``, ``-r __ns:=<namespace>`` (made absolute).
    parameters : list, optional
        Dicts (nested ones flattened with '.'; values: scalars, substitutions, evaluated
        with YAML rules, or ``ParameterValue``), each written to a params file as the real
        one does, or params-file paths (str or substitutions); one ``--params-file`` each,
        in order. A path that is not a file is skipped with a warning, as the real one does.
    remappings : list of (from, to), optional
        ``-r from:=to``.
    arguments : list, optional
        Arguments before ``--ros-args``.
    output : str
        ``'screen'``, ``'log'``, ``'both'`` or ``'own_log'``.
    additional_env : dict, optional
        Environment variables added to the process's.
    **kwargs
        Refused (``ros_arguments``, ``exec_name``, ``condition``, ``respawn``, ...).
    """

    STUB_ACTION = True

    def __init__(self, *, executable: Any, package: Any = None, name: Any = None,
                 namespace: Any = None, parameters: Optional[List[Any]] = None,
                 remappings: Optional[List[Tuple[Any, Any]]] = None,
                 arguments: Optional[List[Any]] = None, output: str = 'log',
                 additional_env: Optional[Dict[Any, Any]] = None, **kwargs: Any) -> None:
        refuse_keywords('Node', kwargs)
        if package is None:
            raise UnsupportedByStub('Node without package is not implemented by the stand-in')
        if output not in OUTPUTS:
            raise ValueError(f'Node output must be one of {OUTPUTS}, got {output!r}')
        if parameters is not None and not isinstance(parameters, list):
            raise TypeError("Node 'parameters' must be a list")
        self.package = normalize_to_list_of_substitutions(package)
        self.executable = normalize_to_list_of_substitutions(executable)
        self.name = None if name is None else normalize_to_list_of_substitutions(name)
        self.namespace = (None if namespace is None
                          else normalize_to_list_of_substitutions(namespace))
        self.parameters: List[Any] = []
        for entry in parameters or []:
            if isinstance(entry, Mapping):
                self.parameters.append(_normalize_parameter_dict(entry))
            else:
                if isinstance(entry, Path):
                    entry = str(entry)
                self.parameters.append(('file', normalize_to_list_of_substitutions(entry)))
        self.remappings = [(normalize_to_list_of_substitutions(a),
                            normalize_to_list_of_substitutions(b))
                           for a, b in (remappings or [])]
        self.arguments = [normalize_to_list_of_substitutions(a) for a in (arguments or [])]
        self.output = output
        self.additional_env = [(normalize_to_list_of_substitutions(k),
                                normalize_to_list_of_substitutions(v))
                               for k, v in (additional_env or {}).items()]

    def execute(self, context: LaunchContext, params_dir: Path) -> NodeProcess:
        """
        Expand everything into the process ``ros2 launch`` starts.

        Parameters
        ----------
        context : LaunchContext
            The launch context.
        params_dir : pathlib.Path
            Where the params files of dict parameters are written (the real one uses the
            system's temporary directory).

        Returns
        -------
        NodeProcess
            The command and environment.

        Raises
        ------
        SubstitutionFailure
            If the executable is not in ``<prefix>/lib/<package>``.
        """
        package = perform_substitutions(context, self.package)
        executable = perform_substitutions(context, self.executable)
        # ExecutableInPackage
        path = os.path.join(get_package_prefix(package), 'lib', package, executable)
        if not os.path.exists(path):
            raise SubstitutionFailure(f"executable '{executable}' not found on the libexec "
                                      f"directory '{os.path.dirname(path)}'")
        cmd = [path] + [perform_substitutions(context, a) for a in self.arguments]
        cmd.append('--ros-args')
        node_name = ''
        if self.name is not None:
            node_name = perform_substitutions(context, self.name)
            cmd += ['-r', f'__node:={node_name}']
        namespace = ''
        if self.namespace is not None:
            namespace = perform_substitutions(context, self.namespace)
            if not namespace.startswith('/'):
                namespace = '/' + namespace
            cmd += ['-r', f'__ns:={namespace}']
        full_name = (namespace.rstrip('/') + '/' + node_name) if node_name and namespace \
            else '/**'
        evaluated: List[Any] = []
        for entry in self.parameters:
            if isinstance(entry, tuple):
                param_file = perform_substitutions(context, entry[1])
                evaluated.append(param_file)
                if not os.path.isfile(param_file):
                    context.warnings.append(f'Parameter file path is not a file: {param_file}')
                    continue
            else:
                values = _evaluate_parameter_dict(context, entry)
                evaluated.append(values)
                params_dir.mkdir(parents=True, exist_ok=True)
                with tempfile.NamedTemporaryFile('w', prefix='launch_params_', dir=params_dir,
                                                 delete=False) as h:
                    yaml.dump({full_name: {'ros__parameters': values}}, h,
                              default_flow_style=False)
                    param_file = h.name
            cmd += ['--params-file', param_file]
        for a, b in self.remappings:
            cmd += ['-r', f'{perform_substitutions(context, a)}:='
                          f'{perform_substitutions(context, b)}']
        env = {perform_substitutions(context, k): perform_substitutions(context, v)
               for k, v in self.additional_env}
        return NodeProcess(cmd=cmd, additional_env=env, executable=executable,
                           node_name=node_name, namespace=namespace, output=self.output,
                           parameters=evaluated)


def __getattr__(name: str) -> Any:
    if name.startswith('__'):
        raise AttributeError(name)
    raise refuse_missing('launch_ros.actions', name)
