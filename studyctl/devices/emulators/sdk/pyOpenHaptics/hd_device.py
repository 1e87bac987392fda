"""``pyOpenHaptics.hd_device`` on studyctl's emulator: the same constructor (init, enable force, start the
scheduler, schedule the callback)."""

from . import hd
from .hd_callback import hdAsyncSheduler, hdSyncSheduler


class HapticDevice:
    def __init__(self, callback, device_name: str = "Default Device", scheduler_type: str = "async"):
        self.id = hd.init_device(device_name)
        if self.id is None:
            return
        hd.enable_force()
        hd.start_scheduler()
        self.scheduler(callback, scheduler_type)

    def close(self):
        hd.stop_scheduler()
        hd.close_device(self.id)

    def scheduler(self, callback, scheduler_type):
        if scheduler_type == "async":
            hdAsyncSheduler(callback)
        else:
            hdSyncSheduler(callback)
