"""LinuxCNC: mebm's driver (``linuxcnc://HOST:PORT?joint=N&...``) and its simulated machine
(a LinuxCNC configuration whose HAL simulates feed axes with a backlash, ``sim/``)."""

from acquisition.linuxcnc.driver import LinuxcncDriver
from acquisition.linuxcnc.url import driver_from_linuxcnc_url

__all__ = ["LinuxcncDriver", "driver_from_linuxcnc_url"]
