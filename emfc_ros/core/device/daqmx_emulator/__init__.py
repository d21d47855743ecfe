"""
An emulated NI-DAQmx device for tests and dry runs (``emfc-daqmx-emulator``).

- :mod:`.model`: the device (tasks, one sample clock, AI and AO buffers, the watchdog timer,
  NI's error semantics) on an injected clock, without gRPC;
- :mod:`.plant`: the simulated balance wired to its terminals (``docs/daqmx.md``);
- :mod:`.server`: NI's ``NiDAQmx`` gRPC service over the device, as the NI gRPC Device Server
  presents a real one to the ``nidaqmx`` client (needs the ``daqmx`` extra).
"""
