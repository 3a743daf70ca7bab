"""Real PHANTOM Omni devices through the OpenHaptics HD library (``libHD.so``), via ctypes.

One `OpenHapticsRig` opens the named devices (e.g. "Left Device" and "Right Device", as
configured in the Phantom Configuration tool), checks their calibration, enables force output
with the library's ramping and clamping, and runs one scheduler callback that serves all of
them: begin a frame on every device, read positions and buttons, call the servo tick, set the
forces, end every frame. HD error codes become `HDError` exceptions carrying their names.

The library is loaded only when a rig is opened (set ``BRAINSIM_LIBHD`` to its path if it is
not on the loader's path). The tests drive this binding against a fake ``libHD.so`` built from
tests/fake_libhd/fake_libhd.c.
"""

from __future__ import annotations

import ctypes
import math
import os
import threading
from dataclasses import dataclass

from sim.devices.base import DeviceState, OmniSpec
from sim.errors import DeviceError

# hdDefines.h (OpenHaptics 3)
HD_SUCCESS = 0x0000
HD_CURRENT_BUTTONS = 0x2000
HD_CURRENT_POSITION = 0x2050
HD_CURRENT_FORCE = 0x2700
HD_CALIBRATION_STYLE = 0x2555
HD_NOMINAL_MAX_FORCE = 0x2603
HD_NOMINAL_MAX_CONTINUOUS_FORCE = 0x2604
HD_FORCE_OUTPUT = 0x4000
HD_MAX_FORCE_CLAMPING = 0x4001
HD_FORCE_RAMPING = 0x4002
HD_CALIBRATION_OK = 0x5000
HD_CALIBRATION_NEEDS_UPDATE = 0x5001
HD_CALIBRATION_NEEDS_MANUAL_INPUT = 0x5002
HD_INVALID_HANDLE = 0xFFFFFFFF
HD_CALLBACK_DONE = 0
HD_CALLBACK_CONTINUE = 1
HD_MAX_SCHEDULER_PRIORITY = 0xFFFF

ERROR_NAMES = {
    0x0000: "HD_SUCCESS",
    0x0100: "HD_INVALID_ENUM",
    0x0101: "HD_INVALID_VALUE",
    0x0102: "HD_INVALID_OPERATION",
    0x0103: "HD_INVALID_INPUT_TYPE",
    0x0104: "HD_BAD_HANDLE",
    0x0200: "HD_WARM_MOTORS",
    0x0201: "HD_EXCEEDED_MAX_FORCE",
    0x0202: "HD_EXCEEDED_MAX_FORCE_IMPULSE",
    0x0203: "HD_EXCEEDED_MAX_VELOCITY",
    0x0204: "HD_FORCE_ERROR",
    0x0300: "HD_DEVICE_FAULT",
    0x0301: "HD_DEVICE_ALREADY_INITIATED",
    0x0302: "HD_COMM_ERROR",
    0x0303: "HD_COMM_CONFIG_ERROR",
    0x0304: "HD_TIMER_ERROR",
    0x0400: "HD_ILLEGAL_BEGIN",
    0x0401: "HD_ILLEGAL_END",
    0x0402: "HD_FRAME_ERROR",
    0x0500: "HD_INVALID_PRIORITY",
    0x0501: "HD_SCHEDULER_FULL",
    0x0600: "HD_INVALID_LICENSE",
}
INSTALL_HINT = (
    "the OpenHaptics HD library (libHD.so) was not found: install the OpenHaptics toolkit and the "
    "PHANTOM device driver from 3D Systems, or set BRAINSIM_LIBHD to the library's path; "
    "use device = \"simulated\" to run without a device"
)


class HDError(DeviceError):
    """An error reported by the HD library, with its name (e.g. HD_DEVICE_FAULT)."""

    def __init__(self, code: int, internal: int = 0, where: str = ""):
        self.code, self.internal = code, internal
        self.name = ERROR_NAMES.get(code, f"HD error 0x{code:04x}")
        super().__init__(f"{where}: {self.name} (0x{code:04x}, internal {internal})" if where else f"{self.name} (0x{code:04x})")


class HDErrorInfo(ctypes.Structure):
    _fields_ = [("errorCode", ctypes.c_uint), ("internalErrorCode", ctypes.c_int), ("hHD", ctypes.c_uint)]


CALLBACK = ctypes.CFUNCTYPE(ctypes.c_uint, ctypes.c_void_p)


def load_library(path: str | None = None) -> ctypes.CDLL:
    path = path or os.environ.get("BRAINSIM_LIBHD") or "libHD.so"
    try:
        lib = ctypes.CDLL(path)
    except OSError:
        raise DeviceError(INSTALL_HINT) from None
    c_uint, c_int, c_double_p = ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_double)
    sigs = {
        "hdInitDevice": (c_uint, [ctypes.c_char_p]),
        "hdDisableDevice": (None, [c_uint]),
        "hdMakeCurrentDevice": (None, [c_uint]),
        "hdBeginFrame": (None, [c_uint]),
        "hdEndFrame": (None, [c_uint]),
        "hdGetDoublev": (None, [c_uint, c_double_p]),
        "hdGetIntegerv": (None, [c_uint, ctypes.POINTER(c_int)]),
        "hdSetDoublev": (None, [c_uint, c_double_p]),
        "hdEnable": (None, [c_uint]),
        "hdDisable": (None, [c_uint]),
        "hdGetError": (HDErrorInfo, []),
        "hdCheckCalibration": (c_int, []),
        "hdUpdateCalibration": (None, [c_uint]),
        "hdScheduleAsynchronous": (ctypes.c_ulong, [CALLBACK, ctypes.c_void_p, ctypes.c_ushort]),
        "hdUnschedule": (None, [ctypes.c_ulong]),
        "hdStartScheduler": (None, []),
        "hdStopScheduler": (None, []),
    }
    for name, (res, args) in sigs.items():
        try:
            fn = getattr(lib, name)
        except AttributeError:
            raise DeviceError(f"{path} is not an OpenHaptics HD library: it has no {name}") from None
        fn.restype, fn.argtypes = res, args
    return lib


@dataclass
class _DeviceSlot:
    name: str
    handle: int
    max_force: float
    position: tuple = (math.nan, math.nan, math.nan)  # metres, in the device frame
    button: bool = False
    fault: str | None = None
    force: tuple = (0.0, 0.0, 0.0)


class OpenHapticsRig:
    """The devices of one rig and the single scheduler callback that serves them."""

    def __init__(self, names=("Left Device", "Right Device"), library: str | None = None):
        self.lib = load_library(library)
        self.slots: list[_DeviceSlot] = []
        self.errors: list[HDError] = []  # errors seen inside the callback
        self._tick = None
        self._handle = None
        self._running = False
        self._lock = threading.Lock()
        self._cb = CALLBACK(self._callback)  # keep a reference: the library calls it from C
        try:
            for name in names:
                self.slots.append(self._open(name))
        except Exception:
            self.close()
            raise

    def _check(self, where: str) -> None:
        err = self.lib.hdGetError()
        if err.errorCode != HD_SUCCESS:
            raise HDError(err.errorCode, err.internalErrorCode, where)

    def _open(self, name: str) -> _DeviceSlot:
        lib = self.lib
        handle = lib.hdInitDevice(name.encode())
        self._check(f"opening {name!r}")
        if handle == HD_INVALID_HANDLE:
            raise DeviceError(f"opening {name!r}: invalid handle")
        lib.hdMakeCurrentDevice(handle)
        status = lib.hdCheckCalibration()
        if status == HD_CALIBRATION_NEEDS_UPDATE:
            style = ctypes.c_int(0)
            lib.hdGetIntegerv(HD_CALIBRATION_STYLE, ctypes.byref(style))
            lib.hdUpdateCalibration(style.value)
            self._check(f"calibrating {name!r}")
            status = lib.hdCheckCalibration()
        if status != HD_CALIBRATION_OK:
            lib.hdDisableDevice(handle)
            raise DeviceError(f"{name!r} needs calibration: put the stylus in its inkwell (or run the Phantom test tool) and try again")
        peak = ctypes.c_double(0.0)
        lib.hdGetDoublev(HD_NOMINAL_MAX_FORCE, ctypes.byref(peak))
        lib.hdEnable(HD_FORCE_OUTPUT)
        lib.hdEnable(HD_FORCE_RAMPING)  # the library ramps force up after enabling
        lib.hdEnable(HD_MAX_FORCE_CLAMPING)  # and clamps at the nominal maximum, besides our clamp
        self._check(f"enabling force output on {name!r}")
        return _DeviceSlot(name=name, handle=handle, max_force=min(peak.value or OmniSpec().peak_force_n, OmniSpec().peak_force_n))

    def devices(self) -> list[OpenHapticsDevice]:
        return [OpenHapticsDevice(self, k) for k in range(len(self.slots))]

    def start(self, tick) -> None:
        """Run `tick(t)` from the library's servo thread, once per frame, for all devices."""
        self._tick = tick
        self._t0 = None
        self._frames = 0
        self._running = True
        self._handle = self.lib.hdScheduleAsynchronous(self._cb, None, HD_MAX_SCHEDULER_PRIORITY)
        self._check("scheduling the servo callback")
        self.lib.hdStartScheduler()
        self._check("starting the scheduler")

    def _callback(self, _data) -> int:
        lib = self.lib
        try:
            pos = (ctypes.c_double * 3)()
            buttons = ctypes.c_int(0)
            for s in self.slots:
                lib.hdBeginFrame(s.handle)
                lib.hdGetDoublev(HD_CURRENT_POSITION, pos)
                lib.hdGetIntegerv(HD_CURRENT_BUTTONS, ctypes.byref(buttons))
                err = lib.hdGetError()
                if err.errorCode != HD_SUCCESS:
                    e = HDError(err.errorCode, err.internalErrorCode, s.name)
                    self.errors.append(e)
                    s.fault = e.name
                else:
                    s.fault = None
                    s.position = (pos[0] * 1e-3, pos[1] * 1e-3, pos[2] * 1e-3)  # mm -> m
                    s.button = bool(buttons.value & 1)
            t = self._frames * 1e-3
            self._frames += 1
            if self._tick is not None:
                self._tick(t)  # reads the slots, writes their forces
            out = (ctypes.c_double * 3)()
            for s in self.slots:
                fx, fy, fz = s.force if s.fault is None else (0.0, 0.0, 0.0)
                out[0], out[1], out[2] = fx, fy, fz
                lib.hdMakeCurrentDevice(s.handle)
                lib.hdSetDoublev(HD_CURRENT_FORCE, out)
                lib.hdEndFrame(s.handle)
                err = lib.hdGetError()
                if err.errorCode != HD_SUCCESS:
                    self.errors.append(HDError(err.errorCode, err.internalErrorCode, s.name))
        except Exception as exc:  # never let an exception unwind into C
            self.errors.append(DeviceError(f"servo callback: {exc}"))
            for s in self.slots:
                s.force = (0.0, 0.0, 0.0)
        return HD_CALLBACK_CONTINUE if self._running else HD_CALLBACK_DONE

    def stop(self) -> None:
        self._running = False
        if self._handle is not None:
            self.lib.hdStopScheduler()
            self.lib.hdUnschedule(self._handle)
            self._handle = None

    def close(self) -> None:
        self.stop()
        for s in self.slots:
            self.lib.hdMakeCurrentDevice(s.handle)
            self.lib.hdDisable(HD_FORCE_OUTPUT)
            self.lib.hdDisableDevice(s.handle)
        self.slots = []


class OpenHapticsDevice:
    """One device of a rig under the `HapticDevice` interface (positions in metres, device frame
    offset by `origin`). `read` and `write_force` are called from the rig's callback."""

    def __init__(self, rig: OpenHapticsRig, index: int, origin=(0.0, 0.0, 0.0)):
        self.rig, self.index, self.origin = rig, index, origin
        slot = rig.slots[index]
        self.name = slot.name
        self.spec = OmniSpec(peak_force_n=slot.max_force)

    def read(self, t: float) -> DeviceState:
        s = self.rig.slots[self.index]
        o = self.origin
        p = s.position
        return DeviceState(position=(p[0] + o[0], p[1] + o[1], p[2] + o[2]), button=s.button, fault=s.fault)

    def write_force(self, force) -> None:
        fx, fy, fz = force
        m = math.sqrt(fx * fx + fy * fy + fz * fz)
        peak = self.spec.peak_force_n
        if not math.isfinite(m):
            fx = fy = fz = 0.0
        elif m > peak:  # clamp here too: never rely on the library alone
            fx, fy, fz = fx * peak / m, fy * peak / m, fz * peak / m
        self.rig.slots[self.index].force = (fx, fy, fz)

    def close(self) -> None:
        self.rig.slots[self.index].force = (0.0, 0.0, 0.0)


def open_devices(hands, mesh) -> list[OpenHapticsDevice]:
    """One rig for the scene's hands; a hand's `device_name` (default "Left Device" /
    "Right Device" by order) names its OpenHaptics device. The device frame's origin is
    placed at the hand's start point, as for the simulated device."""
    default = ("Left Device", "Right Device")
    names = [getattr(h, "device_name", None) or default[i] for i, h in enumerate(hands)]
    rig = OpenHapticsRig(names)
    return [OpenHapticsDevice(rig, i, origin=h.script(mesh).start) for i, h in enumerate(hands)]
