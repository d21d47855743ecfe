"""
An emulated NI-DAQmx device (issue 24, in progress; not yet wired into the package).

:mod:`.model` is the device (tasks, one sample clock, AI and AO buffers, NI's error
semantics) on an injected clock, without gRPC; the gRPC servicer over it is to come.
"""
