"""Real PHANTOM Omni devices through the OpenHaptics HD library (``libHD.so``), via ctypes.

One `OpenHapticsRig` (in the servo process) opens the named devices ("Default Device", or the
names set in the vendor's configuration tool) after flushing the error stack, enables force
output with the library's ramping, clamping and software force limit, and runs one scheduler
callback that serves all of them: begin a frame on every device, read positions and buttons,
call the servo tick, set the forces, end every frame. Calibration is done as the vendor's
sample does it: after the scheduler has started, the status is read inside a frame and one
supported style is used (auto, else inkwell, else encoder reset); a device that needs the
inkwell reports a fault (zero force, no grasp) and a notice for the experimenter until it is
calibrated. The vendor's warm-motor scheme scales forces down towards the nominal continuous
force while a motor is warm. HD error codes become `HDError` exceptions carrying their names.

The library is loaded only when a rig is opened (set ``BRAINSIM_LIBHD`` to its path if it is
not on the loader's path). The tests drive this binding against a fake ``libHD.so`` built from
tests/fake_libhd/fake_libhd.c.
"""

from __future__ import annotations

import ctypes
import locale
import math
import os
import re
import threading
from dataclasses import dataclass

from sim.devices.base import DeviceFrame, DeviceState, OmniSpec
from sim.errors import DeviceError

# hdDefines.h (OpenHaptics 3)
HD_SUCCESS = 0x0000
HD_CURRENT_BUTTONS = 0x2000
HD_CURRENT_POSITION = 0x2050
HD_CURRENT_FORCE = 0x2700
HD_CALIBRATION_STYLE = 0x2555
HD_NOMINAL_MAX_FORCE = 0x2603
HD_NOMINAL_MAX_CONTINUOUS_FORCE = 0x2604
HD_MOTOR_TEMPERATURE = 0x2605  # per motor, normalised: 0 room temperature, 1 overheat
HD_FORCE_OUTPUT = 0x4000
HD_MAX_FORCE_CLAMPING = 0x4001
HD_FORCE_RAMPING = 0x4002
HD_SOFTWARE_FORCE_LIMIT = 0x4003
HD_CALIBRATION_ENCODER_RESET, HD_CALIBRATION_AUTO, HD_CALIBRATION_INKWELL = 1 << 0, 1 << 1, 1 << 2
HD_CURRENT_DEVICE = 0xFFFFFFFF
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
    "to run without a device use --device simulated (or --device mouse), or device = \"simulated\" in the scene"
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
    # the vendor's libraries read their configuration files with the C library's number
    # parsing: a decimal-comma locale (de_DE, fr_FR...) must not reach them
    locale.setlocale(locale.LC_NUMERIC, "C")
    path = path or os.environ.get("BRAINSIM_LIBHD") or "libHD.so"
    try:
        lib = ctypes.CDLL(path)
    except OSError as exc:
        raise DeviceError(_load_error(path, str(exc))) from None
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


def _load_error(path: str, message: str) -> str:
    """What the loader's message means: libHD itself missing, or one of its own dependencies
    (named), or not loadable (wrong architecture, damaged)."""
    missing = re.match(r"\s*([^:]+\.so[.\d]*): cannot open shared object file", message)
    asked = os.path.basename(path)
    if missing and os.path.basename(missing.group(1)) != asked:
        return (f"{path} was found but needs {missing.group(1)}, which is missing: install the package that provides it "
                f"(the OpenHaptics installer's dependencies), or add its folder to LD_LIBRARY_PATH")
    if missing or "No such file" in message:
        return INSTALL_HINT
    return f"{path} cannot be loaded: {message.strip()}"


def flush_errors(lib) -> None:
    """Empty the library's error stack: an old error must not be read as the next call's."""
    for _ in range(64):
        if lib.hdGetError().errorCode == HD_SUCCESS:
            return


def nominal_limits(lib) -> tuple[float, float, int]:
    """The current device's nominal peak and continuous force (N) and its supported calibration styles."""
    peak, continuous, styles = ctypes.c_double(0.0), ctypes.c_double(0.0), ctypes.c_int(0)
    lib.hdGetDoublev(HD_NOMINAL_MAX_FORCE, ctypes.byref(peak))
    lib.hdGetDoublev(HD_NOMINAL_MAX_CONTINUOUS_FORCE, ctypes.byref(continuous))
    lib.hdGetIntegerv(HD_CALIBRATION_STYLE, ctypes.byref(styles))
    return peak.value, continuous.value, styles.value


def choose_calibration_style(supported: int) -> int:
    """One style, as the vendor's sample picks it: auto if supported, else inkwell, else encoder reset."""
    for style in (HD_CALIBRATION_AUTO, HD_CALIBRATION_INKWELL, HD_CALIBRATION_ENCODER_RESET):
        if supported & style:
            return style
    return 0


class _WarmMotors:
    """The vendor's warm-motor guard: above 0.7 (normalised motor temperature) a force clamp
    starts at the current force and shrinks 0.1% a tick towards the continuous force; below 0.5
    it grows back 0.1% a tick and is lifted once the force is under it."""

    def __init__(self, continuous: float):
        self.continuous = continuous
        self.clamp = math.inf
        self.down = self.up = False

    def __call__(self, force, temperature: float):
        mag = math.sqrt(force[0] ** 2 + force[1] ** 2 + force[2] ** 2)
        if not self.down and temperature > 0.7:
            self.down, self.up, self.clamp = True, False, max(mag, self.continuous)
        elif self.down and temperature < 0.5:
            self.down, self.up = False, True
        if self.down:
            self.clamp = max(self.clamp * 0.999, self.continuous)
        elif self.up:
            if mag < self.clamp:
                self.up, self.clamp = False, math.inf
            else:
                self.clamp *= 1.001
        if mag > self.clamp:
            s = self.clamp / mag
            return (force[0] * s, force[1] * s, force[2] * s)
        return force


@dataclass
class _DeviceSlot:
    name: str
    handle: int
    max_force: float
    continuous_force: float = 0.88
    style: int = HD_CALIBRATION_AUTO
    calibrated: bool = False
    warm: _WarmMotors | None = None
    temperature: float = 0.0
    warned: bool = False
    position: tuple = (math.nan, math.nan, math.nan)  # metres, in the device frame
    button: bool = False
    fault: str | None = None
    force: tuple = (0.0, 0.0, 0.0)


class OpenHapticsRig:
    """The devices of one rig and the single scheduler callback that serves them."""

    def __init__(self, names=("Default Device",), library: str | None = None):
        self.lib = load_library(library)
        self.slots: list[_DeviceSlot] = []
        self.errors: list[HDError] = []  # errors seen inside the callback
        self.notices: list[str] = []  # for the experimenter: calibration, warm motors
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
        flush_errors(lib)
        handle = lib.hdInitDevice(name.encode())
        self._check(f"opening {name!r} (the names are set in the vendor's configuration tool; --devices picks them)")
        if handle == HD_INVALID_HANDLE:
            raise DeviceError(f"opening {name!r}: invalid handle")
        lib.hdMakeCurrentDevice(handle)
        peak, continuous, supported = nominal_limits(lib)
        self._check(f"reading {name!r}")
        lib.hdEnable(HD_FORCE_OUTPUT)
        lib.hdEnable(HD_FORCE_RAMPING)  # the library ramps force up after enabling
        lib.hdEnable(HD_MAX_FORCE_CLAMPING)  # and clamps at the nominal maximum, besides our clamp
        lib.hdEnable(HD_SOFTWARE_FORCE_LIMIT)  # and refuses forces the device cannot render safely
        self._check(f"enabling force output on {name!r}")
        spec = OmniSpec()
        cont = min(continuous or spec.continuous_force_n, spec.continuous_force_n)
        return _DeviceSlot(name=name, handle=handle, max_force=min(peak or spec.peak_force_n, spec.peak_force_n),
                           continuous_force=cont, style=choose_calibration_style(supported), warm=_WarmMotors(cont))

    def take_notices(self) -> list[str]:
        out, self.notices = self.notices, []
        return out

    def _calibrate(self, s: _DeviceSlot) -> None:
        """Inside the device's frame, after the scheduler has started (the vendor's order)."""
        lib = self.lib
        status = lib.hdCheckCalibration()
        if status == HD_CALIBRATION_NEEDS_UPDATE and s.style in (HD_CALIBRATION_AUTO, HD_CALIBRATION_ENCODER_RESET):
            lib.hdUpdateCalibration(s.style)
            status = lib.hdCheckCalibration()
        if status == HD_CALIBRATION_OK:
            s.calibrated = True
            self.notices.append(f"{s.name}: calibrated")
        elif s.fault != "needs calibration":
            s.fault = "needs calibration"
            how = ("put the stylus in its inkwell" if status == HD_CALIBRATION_NEEDS_MANUAL_INPUT or s.style == HD_CALIBRATION_INKWELL
                   else "move the stylus through the whole workspace")
            self.notices.append(f"{s.name} needs calibration: {how}")

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
            temps = (ctypes.c_double * 6)()
            buttons = ctypes.c_int(0)
            for s in self.slots:
                lib.hdMakeCurrentDevice(s.handle)
                lib.hdBeginFrame(s.handle)
                if not s.calibrated:
                    self._calibrate(s)
                lib.hdGetDoublev(HD_CURRENT_POSITION, pos)
                lib.hdGetIntegerv(HD_CURRENT_BUTTONS, ctypes.byref(buttons))
                lib.hdGetDoublev(HD_MOTOR_TEMPERATURE, temps)
                err = lib.hdGetError()
                if err.errorCode != HD_SUCCESS:
                    e = HDError(err.errorCode, err.internalErrorCode, s.name)
                    self.errors.append(e)
                    s.fault = e.name
                elif s.calibrated:
                    s.fault = None
                    s.position = (pos[0] * 1e-3, pos[1] * 1e-3, pos[2] * 1e-3)  # mm -> m
                    s.button = bool(buttons.value & 1)
                    s.temperature = max(temps[0], temps[1], temps[2])
            t = self._frames * 1e-3
            self._frames += 1
            if self._tick is not None:
                self._tick(t)  # reads the slots, writes their forces
            out = (ctypes.c_double * 3)()
            for s in self.slots:
                f = s.force if s.fault is None else (0.0, 0.0, 0.0)
                fx, fy, fz = s.warm(f, s.temperature)
                if s.warm.down and not s.warned:
                    self.notices.append(f"{s.name}: warm motors; forces are being reduced towards {s.continuous_force:g} N")
                    s.warned = True
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
    """One device of a rig under the `HapticDevice` interface: positions in metres mapped into
    the scene by `frame` (a `DeviceFrame`: aligned with the view, scaled, offset), forces
    rotated back into the device frame. `read` and `write_force` run in the rig's callback."""

    def __init__(self, rig: OpenHapticsRig, index: int, frame: DeviceFrame | None = None):
        self.rig, self.index = rig, index
        self.frame = frame or DeviceFrame()
        slot = rig.slots[index]
        self.name = slot.name
        self.spec = OmniSpec(peak_force_n=slot.max_force, continuous_force_n=slot.continuous_force)

    def read(self, t: float) -> DeviceState:
        s = self.rig.slots[self.index]
        return DeviceState(position=self.frame.to_scene(s.position), button=s.button, fault=s.fault)

    def write_force(self, force) -> None:
        fx, fy, fz = self.frame.force_to_device(force)
        m = math.sqrt(fx * fx + fy * fy + fz * fz)
        peak = self.spec.peak_force_n
        if not math.isfinite(m):
            fx = fy = fz = 0.0
        elif m > peak:  # clamp here too: never rely on the library alone
            fx, fy, fz = fx * peak / m, fy * peak / m, fz * peak / m
        self.rig.slots[self.index].force = (fx, fy, fz)

    def close(self) -> None:
        self.rig.slots[self.index].force = (0.0, 0.0, 0.0)


def open_devices(hands, mesh):
    raise DeviceError("device openhaptics: real devices run in the servo process, in real time (time scale > 0)")
