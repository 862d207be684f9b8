"""Getting recordings in and out: the second layer, above :mod:`thermonet.core`.

Readers and writers for tables (CSV, Parquet, HDF5 through a channel mapping,
:mod:`thermonet.data.io`, :mod:`thermonet.data.mapping`), flight-controller logs (PX4 ULog,
ArduPilot DataFlash, :mod:`thermonet.data.logs`), the autopilots' own correction formulas that
a log's parameters are read back through (:mod:`thermonet.data.firmware`), and the
plausibility warnings about what was read (:mod:`thermonet.data.diagnostics`).  Everything
produces or consumes :class:`~thermonet.core.recording.Dataset`; nothing here loads torch.
"""
