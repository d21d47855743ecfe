"""
The emulated device as an NI gRPC Device Server: NI's ``NiDAQmx`` service over :class:`Device`.

The service definitions are NI's (``nidaqmx._stubs``, shipped with the ``nidaqmx`` client; the
``daqmx`` extra). :class:`DaqmxServicer` implements the calls that analog input and output
tasks on one sample clock, the watchdog timer and the client's own bookkeeping make
(:data:`IMPLEMENTED`); every other call of the service answers as a real server does for a
function the device does not support: the NI-DAQmx error ``FUNCTION_NOT_SUPPORTED_FOR_DEVICE``
(-209876) naming the call. Errors travel as the real server sends them: gRPC status UNKNOWN
with the text as details and the code in the trailing metadata ``ni-error``, which the client
turns into ``nidaqmx.errors.DaqError`` with that code.

A pump thread advances the device clock every few milliseconds, so that the sample clock
runs in real time whether the host calls or not (an unfed watchdog expires on time, an
unwritten output underflows on time).
"""

from __future__ import annotations

import functools
import threading
import time
from typing import Any, Callable, List, Optional, Tuple

import grpc
from nidaqmx._stubs import nidaqmx_pb2 as pb
from nidaqmx._stubs import nidaqmx_pb2_grpc as pb_grpc
import numpy as np
from session_pb2 import Session

from emfc_ros.core.device import daqmx_errors as codes
from emfc_ros.core.device.daqmx_emulator.model import DaqmxError, Device, expand, Task

#: The driver version the server reports (NI-DAQmx 2025 Q3: 25.5.0).
DRIVER_VERSION = (25, 5, 0)
#: Attribute ids (NI-DAQmx's ``DAQmx_*`` constants) this server answers.
ATTR_TASK_NAME = 0x1276
ATTR_TASK_CHANNELS = 0x1273
ATTR_TASK_NUM_CHANS = 0x2181
ATTR_TASK_COMPLETE = 0x1274
ATTR_SAMP_CLK_RATE = 0x1344
ATTR_SAMP_CLK_SRC = 0x1852
ATTR_SAMP_QUANT_SAMP_MODE = 0x1300
ATTR_SAMP_QUANT_SAMP_PER_CHAN = 0x1310
ATTR_SAMP_TIMING_TYPE = 0x1347
ATTR_INPUT_BUF_SIZE = 0x186C
ATTR_OUTPUT_BUF_SIZE = 0x186D
ATTR_READ_AVAIL_SAMP_PER_CHAN = 0x1223
ATTR_READ_CURR_READ_POS = 0x1221
ATTR_READ_TOTAL_ACQUIRED = 0x192A
ATTR_READ_CHANNELS_TO_READ = 0x1823
ATTR_READ_DEFAULT_SAMPLES = 0x31E8      # DefaultNumberOfSamplesToRead: all available
ATTR_WRITE_REGEN_MODE = 0x1453
ATTR_WRITE_SPACE_AVAIL = 0x1460
ATTR_WRITE_TOTAL_GENERATED = 0x192B
ATTR_WRITE_CURR_WRITE_POS = 0x1458
ATTR_CHAN_TYPE = 0x187F
ATTR_CHAN_AI_MEAS_TYPE = 0x0695
ATTR_CHAN_AO_OUTPUT_TYPE = 0x1108
ATTR_CHAN_MIN = (0x17DE, 0x1187)   # AI.Min, AO.Min
ATTR_CHAN_MAX = (0x17DD, 0x1186)   # AI.Max, AO.Max
SYS_DRIVER_VERSION = (0x1272, 0x1923, 0x2F22)
SYS_DEV_NAMES = 0x193B
#: NI-DAQmx values the calls carry.
CONTINUOUS = 10123
FINITE = 10178
ALLOW_REGENERATION = 10097
DONT_ALLOW_REGENERATION = 10158
GROUP_BY_CHANNEL = 0
SAMPLE_CLOCK = 10388
CHAN_AI = 10100
CHAN_AO = 10102
VOLTAGE = 10322
TASK_START, TASK_STOP, TASK_ABORT = 0, 1, 6
WDT_RESET_TIMER, WDT_CLEAR_EXPIRATION = 0, 1
#: Session initialization behaviours (``nidaqmx.SessionInitializationBehavior``).
AUTO, INIT_NEW, ATTACH = 0, 1, 2
#: Longest a read waits for samples, whatever timeout the client asks for [s].
MAX_WAIT_S = 600.0
#: Longest a write waits for buffer space, whatever timeout the client asks for [s].
MAX_WRITE_WAIT_S = 600.0


def _rpc(method: Callable) -> Callable:
    """Run a call under the device lock; a DaqmxError becomes NI's error answer."""

    @functools.wraps(method)
    def wrapper(self: 'DaqmxServicer', request: Any, context: grpc.ServicerContext) -> Any:
        try:
            return method(self, request, context)
        except DaqmxError as exc:
            context.set_trailing_metadata((('ni-error', str(exc.code)),))
            context.abort(grpc.StatusCode.UNKNOWN, str(exc))
    return wrapper


def _unsupported(name: str) -> Callable:
    def call(self: 'DaqmxServicer', request: Any, context: grpc.ServicerContext) -> Any:
        context.set_trailing_metadata(
            (('ni-error', str(codes.FUNCTION_NOT_SUPPORTED_FOR_DEVICE)),))
        context.abort(grpc.StatusCode.UNKNOWN,
                      f'{codes.text(codes.FUNCTION_NOT_SUPPORTED_FOR_DEVICE)}\n'
                      f'Function: {name}\nDevice: {self.device.name} (emulated)')
    call.__name__ = name
    return call


class DaqmxServicer(pb_grpc.NiDAQmxServicer):
    """
    NI's ``NiDAQmx`` service over one emulated device.

    Parameters
    ----------
    device : Device
        The device.
    pump_period_s : float
        How often the pump thread advances the device clock [s]; 0: no pump (tests that
        advance it themselves).
    """

    def __init__(self, device: Device, pump_period_s: float = 0.005) -> None:
        self.device = device
        self.lock = threading.RLock()
        self._unnamed = 0
        self._stop = threading.Event()
        self._pump: Optional[threading.Thread] = None
        self.pump_error: Optional[BaseException] = None
        if pump_period_s > 0:
            self._pump = threading.Thread(target=self._run_pump, args=(pump_period_s,),
                                          daemon=True, name='emfc-daqmx-pump')
            self._pump.start()

    def close(self) -> None:
        """Stop the pump thread."""
        self._stop.set()
        if self._pump is not None:
            self._pump.join(2.0)

    def _run_pump(self, period_s: float) -> None:
        while not self._stop.wait(period_s):
            try:
                with self.lock:
                    self.device.advance()
            except Exception as exc:    # noqa: B902 - kept for the report; the device is dead
                self.pump_error = exc
                return

    def _task(self, session: Session) -> Task:
        return self.device.task(session.name)

    # -- the system ---------------------------------------------------------------------------

    @_rpc
    def GetSystemInfoAttributeUInt32(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Driver version (major, minor, update).

        Parameters
        ----------
        request : nidaqmx_pb2.GetSystemInfoAttributeUInt32Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetSystemInfoAttributeUInt32Response
            ``value``: the part of the driver version asked for.
        """
        attr = request.attribute_raw
        if attr in SYS_DRIVER_VERSION:
            return pb.GetSystemInfoAttributeUInt32Response(
                value=DRIVER_VERSION[SYS_DRIVER_VERSION.index(attr)])
        raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{attr:X}')

    @_rpc
    def GetSystemInfoAttributeString(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        The device names.

        Parameters
        ----------
        request : nidaqmx_pb2.GetSystemInfoAttributeStringRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetSystemInfoAttributeStringResponse
            ``value``: the device's name.
        """
        if request.attribute_raw == SYS_DEV_NAMES:
            return pb.GetSystemInfoAttributeStringResponse(value=self.device.name)
        raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    def GetErrorString(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        The text of an error code (NI's).

        Parameters
        ----------
        request : nidaqmx_pb2.GetErrorStringRequest
            NI's request.
        context : grpc.ServicerContext
            The call (not used).

        Returns
        -------
        nidaqmx_pb2.GetErrorStringResponse
            ``error_string``: the text.
        """
        return pb.GetErrorStringResponse(error_string=codes.text(request.error_code))

    # -- tasks --------------------------------------------------------------------------------

    def _session(self, name: str, behavior: int) -> Tuple[str, bool]:
        """A named session by NI's initialization behaviour: (name, new session)."""
        exists = name in self.device.tasks
        if exists and behavior == INIT_NEW:
            raise DaqmxError(codes.DUPLICATE_TASK, f'Session Name: {name} (exists; attach '
                                                   'to it or clear it)')
        if not exists and behavior == ATTACH:
            raise DaqmxError(codes.INVALID_TASK, f'Session Name: {name} (no such session to '
                                                 'attach to)')
        return name, not exists

    @_rpc
    def CreateTask(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        A new task, or the named session's task (NI's initialization behaviours).

        ``AUTO`` attaches to an existing session of the name or creates it,
        ``INITIALIZE_SERVER_SESSION`` creates it (an existing one is an error),
        ``ATTACH_TO_SERVER_SESSION`` attaches (a missing one is an error). An empty name gets
        NI's ``_unnamedTask<n>``.

        Parameters
        ----------
        request : nidaqmx_pb2.CreateTaskRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.CreateTaskResponse
            ``task``: the session; ``new_session_initialized``: whether it was created.
        """
        with self.lock:
            name = request.session_name
            if not name:
                name = f'_unnamedTask<{self._unnamed}>'
                self._unnamed += 1
            name, new = self._session(name, request.initialization_behavior)
            if new:
                self.device.create_task(name)
            return pb.CreateTaskResponse(task=Session(name=name),
                                         new_session_initialized=new)

    @_rpc
    def ClearTask(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Stop and forget a task.

        Parameters
        ----------
        request : nidaqmx_pb2.ClearTaskRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.ClearTaskResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            self.device.clear(request.task.name)
            return pb.ClearTaskResponse()

    @_rpc
    def StartTask(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Start a task.

        Parameters
        ----------
        request : nidaqmx_pb2.StartTaskRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.StartTaskResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            self.device.start(self._task(request.task))
            return pb.StartTaskResponse()

    @_rpc
    def StopTask(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Stop a task; its latched error, if any, is the answer (as DAQmxStopTask).

        Parameters
        ----------
        request : nidaqmx_pb2.StopTaskRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.StopTaskResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            task = self._task(request.task)
            self.device.stop(task)
            error, task.error = task.error, None
            if error is not None:
                raise error
            return pb.StopTaskResponse()

    @_rpc
    def TaskControl(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Start, stop or abort (verify, commit, reserve and unreserve do nothing here).

        Parameters
        ----------
        request : nidaqmx_pb2.TaskControlRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.TaskControlResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            task = self._task(request.task)
            if request.action_raw == TASK_START:
                self.device.start(task)
            elif request.action_raw in (TASK_STOP, TASK_ABORT):
                self.device.stop(task)
            return pb.TaskControlResponse()

    @_rpc
    def IsTaskDone(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        A continuous task is done only when stopped or failed.

        Parameters
        ----------
        request : nidaqmx_pb2.IsTaskDoneRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.IsTaskDoneResponse
            ``is_task_done``.
        """
        with self.lock:
            task = self._task(request.task)
            self.device.advance()
            return pb.IsTaskDoneResponse(is_task_done=not task.running or
                                         task.error is not None)

    @_rpc
    def GetTaskAttributeString(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Task name, channel names.

        Parameters
        ----------
        request : nidaqmx_pb2.GetTaskAttributeStringRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetTaskAttributeStringResponse
            ``value``: the task's name or its channels' names, comma separated.
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw == ATTR_TASK_NAME:
                return pb.GetTaskAttributeStringResponse(value=task.name)
            if request.attribute_raw == ATTR_TASK_CHANNELS:
                return pb.GetTaskAttributeStringResponse(
                    value=', '.join(c.name for c in task.channels))
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    @_rpc
    def GetTaskAttributeUInt32(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Number of channels.

        Parameters
        ----------
        request : nidaqmx_pb2.GetTaskAttributeUInt32Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetTaskAttributeUInt32Response
            ``value``: the number of channels.
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw == ATTR_TASK_NUM_CHANS:
                return pb.GetTaskAttributeUInt32Response(value=len(task.channels))
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    @_rpc
    def GetTaskAttributeBool(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Task complete.

        Parameters
        ----------
        request : nidaqmx_pb2.GetTaskAttributeBoolRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetTaskAttributeBoolResponse
            ``value``: true when the task is not running.
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw == ATTR_TASK_COMPLETE:
                return pb.GetTaskAttributeBoolResponse(value=not task.running)
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    # -- channels -----------------------------------------------------------------------------

    @_rpc
    def CreateAIVoltageChan(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Voltage inputs (any terminal configuration; the emulated inputs are ideal).

        Parameters
        ----------
        request : nidaqmx_pb2.CreateAIVoltageChanRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.CreateAIVoltageChanResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            self.device.add_channels(self._task(request.task), 'ai', request.physical_channel,
                                     request.name_to_assign_to_channel, request.min_val,
                                     request.max_val)
            return pb.CreateAIVoltageChanResponse()

    @_rpc
    def CreateAOVoltageChan(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Voltage outputs.

        Parameters
        ----------
        request : nidaqmx_pb2.CreateAOVoltageChanRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.CreateAOVoltageChanResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            self.device.add_channels(self._task(request.task), 'ao', request.physical_channel,
                                     request.name_to_assign_to_channel, request.min_val,
                                     request.max_val)
            return pb.CreateAOVoltageChanResponse()

    def _channel(self, request: Any) -> Tuple[Task, Any]:
        # a channel list answers with its first channel's value (NI requires them equal)
        task = self._task(request.task)
        wanted = request.channel.split(',')[0].strip()
        for ch in task.channels:
            if wanted in (ch.name, ''):
                return task, ch
        try:
            first = expand(wanted, self.device.name)[0]
        except (DaqmxError, IndexError, ValueError):
            first = None
        for ch in task.channels:
            if ch.physical == first:
                return task, ch
        raise DaqmxError(codes.INVALID_PHYS_CHAN_NAME, f'Channel Name: {request.channel}')

    @_rpc
    def GetChanAttributeInt32(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Channel type, measurement and output type.

        Parameters
        ----------
        request : nidaqmx_pb2.GetChanAttributeInt32Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetChanAttributeInt32Response
            ``value_raw``: the channel type (CHAN_AI, CHAN_AO) or VOLTAGE.
        """
        with self.lock:
            task, _ = self._channel(request)
            attr = request.attribute_raw
            if attr == ATTR_CHAN_TYPE:
                return pb.GetChanAttributeInt32Response(
                    value_raw=CHAN_AI if task.kind == 'ai' else CHAN_AO)
            if attr in (ATTR_CHAN_AI_MEAS_TYPE, ATTR_CHAN_AO_OUTPUT_TYPE):
                return pb.GetChanAttributeInt32Response(value_raw=VOLTAGE)
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{attr:X}')

    @_rpc
    def GetChanAttributeDouble(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        A channel's minimum and maximum [V].

        Parameters
        ----------
        request : nidaqmx_pb2.GetChanAttributeDoubleRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetChanAttributeDoubleResponse
            ``value``: the minimum or the maximum [V].
        """
        with self.lock:
            _, ch = self._channel(request)
            attr = request.attribute_raw
            if attr in ATTR_CHAN_MIN:
                return pb.GetChanAttributeDoubleResponse(value=ch.min_V)
            if attr in ATTR_CHAN_MAX:
                return pb.GetChanAttributeDoubleResponse(value=ch.max_V)
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{attr:X}')

    # -- timing and triggers ------------------------------------------------------------------

    @_rpc
    def CfgSampClkTiming(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Continuous sample-clock timing (finite acquisitions are not emulated).

        Parameters
        ----------
        request : nidaqmx_pb2.CfgSampClkTimingRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.CfgSampClkTimingResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            task = self._task(request.task)
            if request.sample_mode_raw != CONTINUOUS:
                raise DaqmxError(codes.INVALID_ATTRIBUTE_VALUE,
                                 'Property: SampQuant.SampMode\nRequested Value: '
                                 f'{request.sample_mode_raw}\nSupported (emulated): '
                                 f'Continuous Samples ({CONTINUOUS})')
            rate = float(request.rate)
            buffer = max(int(request.samps_per_chan), _default_buffer(rate))
            self.device.timing(task, request.source, rate, buffer)
            return pb.CfgSampClkTimingResponse()

    @_rpc
    def CfgDigEdgeStartTrig(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Start trigger on the AI start trigger.

        Parameters
        ----------
        request : nidaqmx_pb2.CfgDigEdgeStartTrigRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.CfgDigEdgeStartTrigResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            self.device.start_trigger_on(self._task(request.task), request.trigger_source)
            return pb.CfgDigEdgeStartTrigResponse()

    @_rpc
    def DisableStartTrig(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        No start trigger.

        Parameters
        ----------
        request : nidaqmx_pb2.DisableStartTrigRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.DisableStartTrigResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            self._task(request.task).trigger = ''
            return pb.DisableStartTrigResponse()

    @_rpc
    def GetTimingAttributeDouble(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        The sample clock rate [Hz].

        Parameters
        ----------
        request : nidaqmx_pb2.GetTimingAttributeDoubleRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetTimingAttributeDoubleResponse
            ``value``: the rate [Hz].
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw == ATTR_SAMP_CLK_RATE:
                return pb.GetTimingAttributeDoubleResponse(value=task.rate_Hz)
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    @_rpc
    def SetTimingAttributeDouble(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        The sample clock rate [Hz].

        Parameters
        ----------
        request : nidaqmx_pb2.SetTimingAttributeDoubleRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.SetTimingAttributeDoubleResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw != ATTR_SAMP_CLK_RATE:
                raise DaqmxError(codes.ATTR_NOT_SUPPORTED,
                                 f'Property: 0x{request.attribute_raw:X}')
            self.device.timing(task, task.source, request.value, task.buffer_samples)
            return pb.SetTimingAttributeDoubleResponse()

    @_rpc
    def GetTimingAttributeString(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        The sample clock source.

        Parameters
        ----------
        request : nidaqmx_pb2.GetTimingAttributeStringRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetTimingAttributeStringResponse
            ``value``: the source (``OnboardClock`` when none is set).
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw == ATTR_SAMP_CLK_SRC:
                return pb.GetTimingAttributeStringResponse(value=task.source or 'OnboardClock')
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    @_rpc
    def SetTimingAttributeString(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        The sample clock source.

        Parameters
        ----------
        request : nidaqmx_pb2.SetTimingAttributeStringRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.SetTimingAttributeStringResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw != ATTR_SAMP_CLK_SRC:
                raise DaqmxError(codes.ATTR_NOT_SUPPORTED,
                                 f'Property: 0x{request.attribute_raw:X}')
            self.device.timing(task, request.value, task.rate_Hz or 1000.0,
                               task.buffer_samples)
            return pb.SetTimingAttributeStringResponse()

    @_rpc
    def GetTimingAttributeInt32(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Sample mode (continuous) and timing type (sample clock).

        Parameters
        ----------
        request : nidaqmx_pb2.GetTimingAttributeInt32Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetTimingAttributeInt32Response
            ``value_raw``: CONTINUOUS; SAMPLE_CLOCK, or 10390 (on demand) while the task has
            no rate.
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw == ATTR_SAMP_QUANT_SAMP_MODE:
                return pb.GetTimingAttributeInt32Response(value_raw=CONTINUOUS)
            if request.attribute_raw == ATTR_SAMP_TIMING_TYPE:
                return pb.GetTimingAttributeInt32Response(   # 10390: on demand
                    value_raw=SAMPLE_CLOCK if task.rate_Hz else 10390)
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    @_rpc
    def GetTimingAttributeUInt64(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Samples per channel (the buffer size of a continuous task).

        Parameters
        ----------
        request : nidaqmx_pb2.GetTimingAttributeUInt64Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetTimingAttributeUInt64Response
            ``value``: the buffer size [samples per channel].
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw == ATTR_SAMP_QUANT_SAMP_PER_CHAN:
                return pb.GetTimingAttributeUInt64Response(value=task.buffer_samples)
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    # -- buffers and streams ------------------------------------------------------------------

    @_rpc
    def SetBufferAttributeUInt32(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Input or output buffer size [samples per channel].

        Parameters
        ----------
        request : nidaqmx_pb2.SetBufferAttributeUInt32Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.SetBufferAttributeUInt32Response
            Empty: NI's answer of success.
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw not in (ATTR_INPUT_BUF_SIZE, ATTR_OUTPUT_BUF_SIZE):
                raise DaqmxError(codes.ATTR_NOT_SUPPORTED,
                                 f'Property: 0x{request.attribute_raw:X}')
            task.buffer_samples = max(1, int(request.value))
            return pb.SetBufferAttributeUInt32Response()

    @_rpc
    def GetBufferAttributeUInt32(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Input or output buffer size [samples per channel].

        Parameters
        ----------
        request : nidaqmx_pb2.GetBufferAttributeUInt32Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetBufferAttributeUInt32Response
            ``value``: the buffer size [samples per channel].
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw not in (ATTR_INPUT_BUF_SIZE, ATTR_OUTPUT_BUF_SIZE):
                raise DaqmxError(codes.ATTR_NOT_SUPPORTED,
                                 f'Property: 0x{request.attribute_raw:X}')
            return pb.GetBufferAttributeUInt32Response(value=task.buffer_samples)

    @_rpc
    def SetWriteAttributeInt32(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Regeneration mode.

        Parameters
        ----------
        request : nidaqmx_pb2.SetWriteAttributeInt32Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.SetWriteAttributeInt32Response
            Empty: NI's answer of success.
        """
        with self.lock:
            task = self._task(request.task)
            value = request.value_raw
            if request.attribute_raw != ATTR_WRITE_REGEN_MODE:
                raise DaqmxError(codes.ATTR_NOT_SUPPORTED,
                                 f'Property: 0x{request.attribute_raw:X}')
            if value not in (ALLOW_REGENERATION, DONT_ALLOW_REGENERATION):
                raise DaqmxError(codes.INVALID_ATTRIBUTE_VALUE,
                                 f'Property: Write.RegenMode\nRequested Value: {value}')
            task.regeneration = value == ALLOW_REGENERATION
            return pb.SetWriteAttributeInt32Response()

    @_rpc
    def GetWriteAttributeInt32(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Regeneration mode.

        Parameters
        ----------
        request : nidaqmx_pb2.GetWriteAttributeInt32Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetWriteAttributeInt32Response
            ``value_raw``: ALLOW_REGENERATION or DONT_ALLOW_REGENERATION.
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw != ATTR_WRITE_REGEN_MODE:
                raise DaqmxError(codes.ATTR_NOT_SUPPORTED,
                                 f'Property: 0x{request.attribute_raw:X}')
            return pb.GetWriteAttributeInt32Response(
                value_raw=ALLOW_REGENERATION if task.regeneration else DONT_ALLOW_REGENERATION)

    @_rpc
    def GetWriteAttributeUInt64(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Samples generated so far; the write position.

        Parameters
        ----------
        request : nidaqmx_pb2.GetWriteAttributeUInt64Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetWriteAttributeUInt64Response
            ``value``: the samples generated or the write position [samples per channel].
        """
        with self.lock:
            task = self._task(request.task)
            self.device.advance()
            if request.attribute_raw == ATTR_WRITE_TOTAL_GENERATED:
                return pb.GetWriteAttributeUInt64Response(value=task.produced)
            if request.attribute_raw == ATTR_WRITE_CURR_WRITE_POS:
                return pb.GetWriteAttributeUInt64Response(value=task.consumed)
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    @_rpc
    def GetWriteAttributeUInt32(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Space available in the output buffer [samples per channel].

        Parameters
        ----------
        request : nidaqmx_pb2.GetWriteAttributeUInt32Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetWriteAttributeUInt32Response
            ``value``: the free space [samples per channel].
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw == ATTR_WRITE_SPACE_AVAIL:
                space = min(self.device.space_available(task), 0xFFFFFFFF)
                return pb.GetWriteAttributeUInt32Response(value=space)
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    @_rpc
    def GetReadAttributeUInt32(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Samples available to read [per channel].

        Parameters
        ----------
        request : nidaqmx_pb2.GetReadAttributeUInt32Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetReadAttributeUInt32Response
            ``value``: the samples available [per channel]; 0 while the task is not running.
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw in (ATTR_READ_AVAIL_SAMP_PER_CHAN,
                                         ATTR_READ_DEFAULT_SAMPLES):
                avail = self.device.available(task) if task.running else 0
                return pb.GetReadAttributeUInt32Response(value=avail)
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    @_rpc
    def GetReadAttributeUInt64(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Read position; samples acquired so far.

        Parameters
        ----------
        request : nidaqmx_pb2.GetReadAttributeUInt64Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetReadAttributeUInt64Response
            ``value``: the read position or the samples acquired [per channel].
        """
        with self.lock:
            task = self._task(request.task)
            self.device.advance()
            if request.attribute_raw == ATTR_READ_CURR_READ_POS:
                return pb.GetReadAttributeUInt64Response(value=task.consumed)
            if request.attribute_raw == ATTR_READ_TOTAL_ACQUIRED:
                return pb.GetReadAttributeUInt64Response(value=task.produced)
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    @_rpc
    def GetReadAttributeString(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        The channels a read returns (all of the task's).

        Parameters
        ----------
        request : nidaqmx_pb2.GetReadAttributeStringRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.GetReadAttributeStringResponse
            ``value``: the channels' names, comma separated.
        """
        with self.lock:
            task = self._task(request.task)
            if request.attribute_raw == ATTR_READ_CHANNELS_TO_READ:
                return pb.GetReadAttributeStringResponse(
                    value=', '.join(c.name for c in task.channels))
            raise DaqmxError(codes.ATTR_NOT_SUPPORTED, f'Property: 0x{request.attribute_raw:X}')

    @_rpc
    def ReadAnalogF64(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Read samples of a running AI task, waiting for them up to the timeout.

        ``num_samps_per_chan`` -1 reads what is there; a timeout of -1 waits (at most
        :data:`MAX_WAIT_S`). Too few samples by the timeout: SAMPLES_NOT_YET_AVAILABLE.

        Parameters
        ----------
        request : nidaqmx_pb2.ReadAnalogF64Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.ReadAnalogF64Response
            ``read_array``: the samples [V], grouped by channel or interleaved as the
            request's fill mode asks; ``samps_per_chan_read``.
        """
        want = int(request.num_samps_per_chan)
        timeout = float(request.timeout)
        deadline = time.monotonic() + (MAX_WAIT_S if timeout < 0 else min(timeout, MAX_WAIT_S))
        while True:
            with self.lock:
                task = self._task(request.task)
                avail = self.device.available(task) if task.running else 0
                n = avail if want < 0 else want
                if avail >= n or time.monotonic() >= deadline or task.error is not None \
                        or not task.running:
                    values = self.device.read(task, n)
                    break
                rate = task.rate_Hz
            time.sleep(min(max(deadline - time.monotonic(), 0.0),
                           max((n - avail) / rate, 0.0005)))
        if request.fill_mode_raw != GROUP_BY_CHANNEL:
            values = values.T
        return pb.ReadAnalogF64Response(read_array=values.ravel().tolist(),
                                        samps_per_chan_read=n)

    @_rpc
    def WriteAnalogF64(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Write samples to an AO task's buffer (on demand: applied at once).

        Parameters
        ----------
        request : nidaqmx_pb2.WriteAnalogF64Request
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.WriteAnalogF64Response
            ``samps_per_chan_written``.

        Samples that do not fit in the buffer go in as the running task frees space (the
        lock released in between), for at most the request's ``timeout`` [s] (-1: at most
        :data:`MAX_WRITE_WAIT_S`); then NI's ``SAMPLES_CAN_NOT_YET_BE_WRITTEN``, with what
        was written staying written, as the driver does.
        """
        timeout = float(request.timeout)
        end = time.monotonic() + (MAX_WRITE_WAIT_S if timeout < 0 else timeout)
        n = int(request.num_samps_per_chan)
        data = np.asarray(request.write_array, dtype=np.float64)
        values: Optional[np.ndarray] = None
        done = 0
        while True:
            with self.lock:
                task = self._task(request.task)     # (each time: it may have been cleared)
                if values is None:
                    chans = len(task.channels)
                    if data.size != n * chans:
                        raise DaqmxError(codes.INVALID_ATTRIBUTE_VALUE,
                                         f'Task Name: {task.name}\nSamples per channel: {n}\n'
                                         f'Values written: {data.size} for {chans} channels')
                    by_channel = request.data_layout_raw == GROUP_BY_CHANNEL
                    values = data.reshape(chans, n) if by_channel else data.reshape(n, chans).T
                take = min(self.device.space_available(task), n - done)
                if take > 0 or n == 0:
                    done += self.device.write(task, values[:, done:done + take])
                if request.auto_start and not task.running and not task.armed:
                    self.device.start(task)
                if done == n:
                    return pb.WriteAnalogF64Response(samps_per_chan_written=done)
                left = end - time.monotonic()
                if left <= 0 or not task.running:
                    raise DaqmxError(codes.SAMPLES_CAN_NOT_YET_BE_WRITTEN,
                                     f'Task Name: {task.name}\nSamples to write: {n}\n'
                                     f'Samples written: {done}')
                # a quarter of the buffer (or what is left) frees up in this time
                wait = min(max(min(n - done, task.buffer_samples // 4) / task.rate_Hz, 1e-3),
                           left)
            time.sleep(wait)

    # -- the watchdog timer -------------------------------------------------------------------

    @_rpc
    def CreateWatchdogTimerTaskEx(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        A watchdog timer task of the device (expiration states configured next).

        Parameters
        ----------
        request : nidaqmx_pb2.CreateWatchdogTimerTaskExRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.CreateWatchdogTimerTaskExResponse
            ``task``: the session; ``new_session_initialized``: whether it was created.
        """
        with self.lock:
            if request.device_name != self.device.name:
                raise DaqmxError(codes.DEV_CANNOT_BE_ACCESSED, f'Device: {request.device_name}')
            name = request.session_name or f'_unnamedTask<{self._unnamed}>'
            self._unnamed += not request.session_name
            name, new = self._session(name, request.initialization_behavior)
            if new:
                self.device.create_watchdog(name, float(request.timeout), {})
            return pb.CreateWatchdogTimerTaskExResponse(task=Session(name=name),
                                                        new_session_initialized=new)

    @_rpc
    def CfgWatchdogAOExpirStates(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Voltage expiration states of analog outputs.

        Parameters
        ----------
        request : nidaqmx_pb2.CfgWatchdogAOExpirStatesRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.CfgWatchdogAOExpirStatesResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            dog = self.device.watchdog
            if dog is None or dog.task != request.task.name:
                raise DaqmxError(codes.INVALID_TASK, f'Task Name: {request.task.name}')
            if not self.device.ao_watchdog:
                # a watchdog of digital lines only (an X Series device's: DIO and PFI)
                raise DaqmxError(codes.ATTR_NOT_SUPPORTED,
                                 f'Property: Watchdog.AO.ExpirState\nDevice: {self.device.name}')
            terms = expand(request.channel_names, self.device.name)
            states = list(request.expir_state_array)
            if len(states) != len(terms) or any(t != VOLTAGE for t in request.output_type_array):
                raise DaqmxError(codes.INVALID_ATTRIBUTE_VALUE,
                                 'Property: AO.ExpirState\nOne voltage state per channel')
            for term in terms:
                if term not in self.device.ao_terminals:
                    raise DaqmxError(codes.INVALID_PHYS_CHAN_NAME,
                                     f'Physical Channel Name: {term}')
            dog.expiration_V.update(zip(terms, (float(s) for s in states)))
            return pb.CfgWatchdogAOExpirStatesResponse()

    @_rpc
    def ControlWatchdogTask(self, request: Any, context: Any) -> Any:  # noqa: N802
        """
        Reset the timer (feed it) or clear an expiration.

        Parameters
        ----------
        request : nidaqmx_pb2.ControlWatchdogTaskRequest
            NI's request.
        context : grpc.ServicerContext
            The call; a DAQmx error aborts it with status UNKNOWN and the code in the trailing
            metadata ``ni-error``.

        Returns
        -------
        nidaqmx_pb2.ControlWatchdogTaskResponse
            Empty: NI's answer of success.
        """
        with self.lock:
            dog = self.device.watchdog
            if dog is None or dog.task != request.task.name:
                raise DaqmxError(codes.INVALID_TASK, f'Task Name: {request.task.name}')
            if request.action_raw == WDT_RESET_TIMER:
                self.device.feed_watchdog()
            elif request.action_raw == WDT_CLEAR_EXPIRATION:
                self.device.clear_expiration()
            return pb.ControlWatchdogTaskResponse()


def _default_buffer(rate_Hz: float) -> int:
    """The default buffer of a continuous input task for a sample rate (NI's) [samples]."""
    if rate_Hz <= 100:
        return 1000
    if rate_Hz <= 10000:
        return 10000
    if rate_Hz <= 1e6:
        return 100000
    return 1000000


#: The calls :class:`DaqmxServicer` implements.
IMPLEMENTED: Tuple[str, ...] = tuple(sorted(
    n for n, v in vars(DaqmxServicer).items() if n[:1].isupper() and callable(v)))

for _name in dir(pb_grpc.NiDAQmxServicer):
    if _name[:1].isupper() and _name not in IMPLEMENTED:
        setattr(DaqmxServicer, _name, _unsupported(_name))


def serve(servicer: DaqmxServicer, address: str = '127.0.0.1:0',
          max_workers: int = 8) -> Tuple[grpc.Server, int]:
    """
    Serve the servicer on an address (``host:port``; port 0 picks a free one).

    Parameters
    ----------
    servicer : DaqmxServicer
        The service.
    address : str
        Where to listen.
    max_workers : int
        Threads answering calls.

    Returns
    -------
    server : grpc.Server
        The started server (``server.stop(grace)`` ends it).
    port : int
        The bound port.
    """
    from concurrent import futures
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=max_workers),
                         options=[('grpc.max_receive_message_length', 64 << 20),
                                  ('grpc.max_send_message_length', 64 << 20)])
    pb_grpc.add_NiDAQmxServicer_to_server(servicer, server)
    port = server.add_insecure_port(address)
    if port == 0:
        raise OSError(f'could not listen on {address}')
    server.start()
    return server, port


__all__: List[str] = ['DaqmxServicer', 'IMPLEMENTED', 'serve', 'DRIVER_VERSION']
