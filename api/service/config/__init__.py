"""The service's configuration, apart from everything else.

- :mod:`api.service.config.settings`: the settings (frozen dataclasses) and the embedded
  defaults, the demo's;
- :mod:`api.service.config.loading`: the TOML file and the environment overrides, every
  option checked with an error that names it;
- :mod:`api.service.config.input`: what an admin may configure at run time (machines, axes,
  tasks, schedules), validated once for the REST API and the dashboard, and an axis'
  controller URL completed and checked (register profile, CANopen table, trigger).
"""
