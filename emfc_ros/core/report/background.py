"""
Report plots drawn in worker processes while the identification and the other files go on.

:class:`PlotPool` starts its workers (``spawn``: safe in a process with DDS threads) at once, so
that they import matplotlib while the caller still records or identifies. Plots are submitted as
soon as their data exist (:meth:`PlotPool.submit_step`: the coherences after the FRF step, the
static characteristics after the static step; :func:`~emfc_ros.core.report.writer.write_report`
submits the rest) and written by the workers; :meth:`PlotPool.wait` collects them. Each job
carries only the data its figure shows (one section's traces, not the whole result).

The emfc-experiment runner uses it (``docs/identification_results.md``); a failed plot is
reported, never silently dropped.
"""

from __future__ import annotations

from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field
import gc
import multiprocessing
import os
from pathlib import Path
import re
import signal
import threading
import time
from types import SimpleNamespace
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

#: Longest wait for all plots [s] (a stuck worker must not hang the run).
WAIT_S = 300.0
#: Niceness the workers add to their own (lower priority than the caller).
WORKER_NICENESS = 10


#: Order in which the workers get the figures of one step: the slowest to draw first
#: (measured per figure, figures reused: the residual analysis with its two or three panels
#: 0.11-0.20 s, the pole-zero map 0.11-0.20 s, a Bode diagram or a time series 0.08-0.13 s),
#: so that the two workers end close together and the last figure done is a quick one.
SUBMIT_ORDER = {'resid': 0, 'pole_zero': 1, 'bode': 2, 'time': 3, 'static': 4, 'coherence': 5}


def slowest_first(jobs: Sequence['PlotJob']) -> List['PlotJob']:
    """
    Figures in the order the workers should draw them (:data:`SUBMIT_ORDER`).

    Parameters
    ----------
    jobs : sequence of PlotJob
        The figures.

    Returns
    -------
    list of PlotJob
        The same, the slowest kinds first, in their given order within a kind.
    """
    return sorted(jobs, key=lambda job: SUBMIT_ORDER.get(job.kind, len(SUBMIT_ORDER)))


def _file_name(text: str) -> str:
    return re.sub(r'[^A-Za-z0-9_.-]+', '_', text)


@dataclass(frozen=True)
class PlotJob:
    """
    One figure: what to draw and where.

    Attributes
    ----------
    path : Path
        The PNG.
    kind : str
        ``'bode'``, ``'coherence'``, ``'time'``, ``'resid'``, ``'static'`` or ``'pole_zero'``.
    args : tuple
        The drawing function's data arguments (picklable, slim).
    key : str
        What the figure shows beyond its path: the grey-box fit it draws (:func:`fit_key`),
        empty for figures of the measurement alone. A figure queued again with another key
        is drawn again (the later file replaces the earlier).
    """

    path: Path
    kind: str
    args: Tuple[Any, ...] = field(default_factory=tuple)
    key: str = ''


def _slim_greybox(greybox: Any, section: str) -> SimpleNamespace:
    """The parts of a grey-box result that one section's figures show."""
    fit = SimpleNamespace(sections=tuple(s for s in greybox.fit.sections if s.name == section))
    inputs = getattr(greybox, 'inputs_V', {})
    return SimpleNamespace(time_s={section: greybox.time_s[section]},
                           measured_m={section: greybox.measured_m[section]},
                           simulated_m={section: greybox.simulated_m[section]},
                           inputs_V={section: inputs[section]} if section in inputs else {},
                           fit=fit)


def fit_key(greybox: Any) -> str:
    """
    The identity of a grey-box fit in figure keys (its parameter values).

    Parameters
    ----------
    greybox : BalanceGreyboxResult or None
        The grey-box result (or the early view of :func:`step_jobs` ``'greybox_fit'``).

    Returns
    -------
    str
        ``''`` without a grey-box result.
    """
    if greybox is None:
        return ''
    values = sorted((str(k), float(v)) for k, v in greybox.fit.parameters.items())
    return 'greybox ' + repr(values)


def step_jobs(step: str, result: Any, out: Path) -> List[PlotJob]:
    """
    The figures a finished pipeline step makes possible (before the grey-box fit ends).

    Parameters
    ----------
    step : str
        ``'frf'`` (coherences), ``'static'`` (static characteristics), ``'greybox_model'``
        (the figures of the fitted model alone: Bode diagrams with the model and the
        pole-zero map, drawn while the fit checks its derivatives) or ``'greybox_fit'``
        (every figure of the grey-box fit: those, time series and residual analyses; drawn
        while the fit's residual tests and checks run; a figure of ``'greybox_model'`` with
        the same parameters is not drawn again); others give none.
    result : IdentificationResult
        The result so far (for ``'greybox_model'`` and ``'greybox_fit'`` an object with
        ``frfs`` and ``greybox``).
    out : Path
        The report folder.

    Returns
    -------
    list of PlotJob
        The jobs.
    """
    out = Path(out)
    jobs = []
    if step == 'frf':
        for frf in result.frfs:
            jobs.append(PlotJob(out / f'coherence_{_file_name(frf.name)}.png', 'coherence',
                                (frf,)))
    elif step == 'static' and getattr(result, 'static', None) is not None:
        for key, fit in result.static.fits.items():
            points = getattr(result.static, 'points', {}).get(key)
            if points is not None:
                jobs.append(PlotJob(out / f'static_{_file_name(key)}.png', 'static',
                                    (key, fit, points[0], points[1])))
    elif step == 'greybox_model' and result.greybox is not None:
        key = fit_key(result.greybox)
        jobs = [PlotJob(out / f'bode_{_file_name(frf.name)}.png', 'bode', (frf,), key)
                for frf in result.frfs if frf.model_response is not None]
        jobs.append(_pole_zero_job(result, out, key))
    elif step == 'greybox_fit' and result.greybox is not None:
        jobs = [job for job in report_jobs(result, out) if job.key]
    return jobs


def _pole_zero_job(result: Any, out: Path, key: str) -> PlotJob:
    """The pole-zero map: every transfer-function fit and the grey-box linearisation."""
    frfs = [SimpleNamespace(name=r.name, fit=r.fit) for r in result.frfs]
    greybox = (SimpleNamespace(linear_model=result.greybox.linear_model)
               if result.greybox is not None else None)
    return PlotJob(out / 'pole_zero.png', 'pole_zero',
                   (SimpleNamespace(frfs=frfs, greybox=greybox),), key)


def report_jobs(result: Any, out: Path) -> List[PlotJob]:
    """
    Every figure of a report, in the order the summary lists them.

    Parameters
    ----------
    result : IdentificationResult
        The pipeline's result.
    out : Path
        The report folder.

    Returns
    -------
    list of PlotJob
        Bode and coherence per FRF, time series and residual analysis per grey-box section,
        the static characteristics and the pole-zero map.
    """
    out = Path(out)
    coherence = {j.path: j for j in step_jobs('frf', result, out)}
    key = fit_key(result.greybox)
    jobs = []
    for frf in result.frfs:
        stem = _file_name(frf.name)
        jobs.append(PlotJob(out / f'bode_{stem}.png', 'bode', (frf,),
                            key if frf.model_response is not None else ''))
        jobs.append(coherence[out / f'coherence_{stem}.png'])
    if result.greybox is not None:
        for name in result.greybox.time_s:
            stem = _file_name(name)
            slim = _slim_greybox(result.greybox, name)
            jobs.append(PlotJob(out / f'time_{stem}.png', 'time', (slim, name), key))
            jobs.append(PlotJob(out / f'resid_{stem}.png', 'resid', (slim, name), key))
    jobs += step_jobs('static', result, out)
    jobs.append(_pole_zero_job(result, out, key))
    return jobs


def draw(job: PlotJob) -> Optional[Path]:
    """
    Draw one figure (in a worker or in the caller's process).

    Parameters
    ----------
    job : PlotJob
        The figure.

    Returns
    -------
    Path or None
        The file written; None when the figure has nothing to show (a residual too short to
        analyse, no model for the pole-zero map).
    """
    from emfc_ros.core.report import plots

    if job.kind == 'bode':
        return plots.plot_bode(job.args[0], job.path)
    if job.kind == 'coherence':
        return plots.plot_coherence(job.args[0], job.path)
    if job.kind == 'time':
        return plots.plot_time_series(job.args[0], job.args[1], job.path)
    if job.kind == 'resid':
        analysis = plots.residual_analysis(job.args[0], job.args[1])
        return None if analysis is None else plots.plot_residuals(analysis, job.path)
    if job.kind == 'static':
        key, fit, x, y = job.args
        return plots.plot_static_fit(key, fit, x, y, job.path)
    if job.kind == 'pole_zero':
        return plots.plot_pole_zero(job.args[0], job.path)
    raise ValueError(f'unknown plot kind {job.kind!r}')


def _warm_up() -> None:
    """Worker start: matplotlib and the plot module imported before the first job."""
    # Ctrl-C in a terminal reaches the whole process group: the caller decides what to do
    # (and stops the workers); a worker must not print a traceback of its own.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # The figures wait for nobody: the caller's identification, on the run's critical path,
    # gets the processor first (on 2 cores the two workers took a third of it from the
    # identification while drawing the early figures).
    try:
        os.nice(WORKER_NICENESS)
    except OSError:
        pass
    # what unpickling the jobs needs (the result's classes) and what drawing them needs
    import emfc_ros.core.ident.pipeline  # noqa: F401
    from emfc_ros.core.blas_threads import pin_single_blas_thread
    # no large products here; two BLAS threads per worker waited for the cores the run's
    # own process held (the residual figures' dot products: 1 s of CPU instead of 0.02 s)
    pin_single_blas_thread()
    from emfc_ros.core.report import plots
    if not plots.matplotlib_available():
        return
    # one small figure drawn to memory: fonts, glyph and text-layout caches filled before the
    # first real figure (its first drawing took twice as long as the next)
    import io
    fig = plots._figure(figsize=(2.0, 1.5))
    ax = fig.subplots()
    ax.semilogx([1.0, 10.0, 100.0], [0.0, 1.0, 0.5], '.-', label='warm-up')
    ax.set_title('warm-up')
    ax.set_ylabel('[1]')
    ax.legend(fontsize=8)
    fig.savefig(io.BytesIO(), format='png', dpi=plots.DPI)
    # matplotlib, the identification's modules and the caches live as long as the worker:
    # the collector need not walk them again in every full collection (about 8 % of the
    # figures' time)
    gc.freeze()


def _ready() -> int:
    return os.getpid()


def _context() -> Any:
    """
    The multiprocessing context of the workers.

    ``forkserver`` where there is one (Linux): a clean server process, started once, imports
    the plotting modules and forks each worker from itself, so that the imports are paid once
    for all workers; ``spawn`` elsewhere. Never ``fork``: the caller has DDS threads.
    """
    if 'forkserver' in multiprocessing.get_all_start_methods():
        ctx = multiprocessing.get_context('forkserver')
        ctx.set_forkserver_preload(['emfc_ros.core.report.background',
                                    'emfc_ros.core.ident.pipeline',
                                    'emfc_ros.core.report.plots', 'matplotlib.pyplot'])
        return ctx
    return multiprocessing.get_context('spawn')


class PlotPool:
    """
    Worker processes drawing report figures.

    The workers are started by a thread of this object (starting them waits for the fork
    server's imports, about a second): the caller goes on at once, and figures submitted
    before they are ready are queued.

    Parameters
    ----------
    workers : int, optional
        Processes (default: the processors this process may use, at most 2).

    Attributes
    ----------
    errors : list of str
        Figures that failed, with the reason (filled by :meth:`wait`).
    """

    def __init__(self, workers: Optional[int] = None) -> None:
        if workers is None:
            try:
                cpus = len(os.sched_getaffinity(0))
            except AttributeError:      # not on Linux
                cpus = os.cpu_count() or 1
            workers = max(1, min(2, cpus))
        self._workers = int(workers)
        self._pool: Optional[ProcessPoolExecutor] = None
        self._futures: Dict[Path, Future] = {}
        self._keys: Dict[Path, str] = {}
        self._pending: List[PlotJob] = []
        self._lock = threading.Lock()
        self._start_error: Optional[BaseException] = None
        self.errors: List[str] = []
        self._starter = threading.Thread(target=self._start, name='plot-pool-start',
                                         daemon=True)
        self._starter.start()

    def _start(self) -> None:
        try:
            pool = ProcessPoolExecutor(max_workers=self._workers, mp_context=_context(),
                                       initializer=_warm_up)
            # start the workers now: they import matplotlib while the caller works
            for _ in range(self._workers):
                pool.submit(_ready)
        except BaseException as exc:    # reported by wait(): the plots are then missing
            self._start_error = exc
            return
        with self._lock:
            self._pool = pool
            pending, self._pending = self._pending, []
            for job in pending:
                self._submit_locked(job)

    def submit(self, jobs: Sequence[PlotJob]) -> None:
        """
        Queue figures; a path already queued with the same key is not drawn twice.

        With another key it is drawn again once the earlier drawing ended, and replaces it.

        Parameters
        ----------
        jobs : sequence of PlotJob
            The figures.
        """
        with self._lock:
            for job in jobs:
                if self._keys.get(job.path) == job.key:
                    continue
                self._keys[job.path] = job.key
                job.path.parent.mkdir(parents=True, exist_ok=True)
                if self._pool is None:
                    self._pending = [j for j in self._pending if j.path != job.path] + [job]
                else:
                    self._submit_locked(job)

    def _submit_locked(self, job: PlotJob) -> None:
        """Submit a figure; one that replaces a figure being drawn waits for it to end."""
        pool = self._pool
        previous = self._futures.get(job.path)
        if previous is None or previous.done():
            self._futures[job.path] = pool.submit(draw, job)
            return
        chained: Future = Future()
        self._futures[job.path] = chained

        def finished(inner: Future) -> None:
            if inner.cancelled():
                chained.cancel()
            elif inner.exception() is not None:
                chained.set_exception(inner.exception())
            else:
                chained.set_result(inner.result())

        def resubmit(_: Future) -> None:
            try:
                pool.submit(draw, job).add_done_callback(finished)
            except BaseException as exc:    # the pool shut down: reported by wait()
                chained.set_exception(exc)

        previous.add_done_callback(resubmit)

    def submit_step(self, step: str, result: Any, out: Path) -> None:
        """
        Queue what a finished pipeline step makes possible (:func:`step_jobs`).

        Parameters
        ----------
        step : str
            The step's name.
        result : IdentificationResult
            The result so far.
        out : Path
            The report folder.
        """
        self.submit(slowest_first(step_jobs(step, result, out)))

    def wait(self, paths: Sequence[Path], timeout_s: float = WAIT_S) -> List[Path]:
        """
        Wait for figures and return the files written, in the order asked.

        Parameters
        ----------
        paths : sequence of Path
            The figures (submitted before).
        timeout_s : float
            Longest wait for all of them [s].

        Returns
        -------
        list of Path
            The files written; failures are appended to :attr:`errors`.
        """
        deadline = time.monotonic() + timeout_s
        self._starter.join(timeout_s)
        if self._start_error is not None:
            self.errors.append(f'the plot workers did not start: {self._start_error!r}')
            return []
        written = []
        for path in paths:
            with self._lock:
                future = self._futures.get(Path(path))
            if future is None:
                self.errors.append(f'{Path(path).name}: never submitted')
                continue
            try:
                got = future.result(timeout=max(0.0, deadline - time.monotonic()))
            except Exception as exc:      # a worker's error or a timeout: reported
                self.errors.append(f'{Path(path).name}: {type(exc).__name__}: {exc}')
                continue
            if got is not None:
                written.append(Path(got))
        return written

    def submit_task(self, fn: Callable[..., Any], *args: Any) -> Future:
        """
        Run another task in a worker, behind the figures already queued.

        Parameters
        ----------
        fn : callable
            A module-level function (pickled to the worker).
        *args
            Its arguments.

        Returns
        -------
        concurrent.futures.Future
            Its result.

        Raises
        ------
        RuntimeError
            If the workers have not started (yet, or at all): the caller runs the task itself.
        """
        with self._lock:
            pool = self._pool
        if pool is None:
            raise RuntimeError('the plot workers have not started')
        return pool.submit(fn, *args)

    @property
    def tasks(self) -> 'PoolTasks':
        """
        The workers as an executor for other work than figures.

        Returns
        -------
        PoolTasks
            For :func:`~emfc_ros.core.ident.pipeline.identify`'s ``executor``.
        """
        return PoolTasks(self)

    def close(self) -> None:
        """Stop the workers (queued figures not yet started are dropped)."""
        self._starter.join()
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> 'PlotPool':
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


@dataclass(frozen=True)
class PoolTasks:
    """
    A :class:`PlotPool`'s workers seen as an executor (:meth:`submit`).

    Attributes
    ----------
    pool : PlotPool
        The pool.
    """

    pool: PlotPool

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        """
        Run a function in a worker (:meth:`PlotPool.submit_task`).

        Parameters
        ----------
        fn : callable
            A module-level function.
        *args
            Its arguments.

        Returns
        -------
        concurrent.futures.Future
            Its result.
        """
        return self.pool.submit_task(fn, *args)
