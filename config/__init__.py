"""The packaged default configuration: the simulated bench (bench-sim.toml), the loopback and compose benches,
the reducer catalogue (reducers.toml), the paper's and the simulator's geometry, the drive's Modbus register map.

Found with ``importlib.resources`` (``tcms_daq.config.packaged_config_dir``), so an installed wheel works from any
directory; ``config/`` at the top of the source tree is a link to this folder. ``--config NAME.toml`` on the
command line finds these files by name when no such file is in the working directory.
"""
