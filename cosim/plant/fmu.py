"""The plant: the Quadrotor FMU (Co-Simulation) behind a small, fast stepping interface.

The FMU is loaded once with fmpy (model description, extraction, FMU2Slave instantiation);
each tick then goes straight to the FMU's C functions through ctypes with preallocated value
reference and value arrays: one fmi2SetReal (7 inputs), one fmi2DoStep, one fmi2GetReal
(20 outputs) and one fmi2GetBoolean (on_ground), without per-call argument conversion. Our
FMU also exports ``quadrotorSetStepGet``, those four calls in one (not FMI; ~1 us per ctypes
call is more than half of a tick's cost); the wrapper uses it when present, and falls back
to the four standard calls for any other build (``fast=False`` forces them).
Every status is checked; a non-OK status raises :class:`cosim.errors.ComponentError`
('plant', ...) carrying the FMU's log messages.

Time is ``t = k * step_size`` from the integer tick counter ``k``; the FMU integrates each
tick with RK4 substeps of at most ``substep`` (1 ms). Runs are bit-identical across
processes and after :meth:`Plant.reset` / :meth:`Plant.set_state`.

Example::

    from cosim.plant.fmu import Plant
    from cosim.scenario.vehicles import MAMBO
    with Plant(MAMBO) as plant:
        for _ in range(200):                       # 1 s
            y = plant.step(*(4 * [MAMBO.u_hover]))
        print(plant.t, y[Y_Z], y[Y_ON_GROUND])
"""

from __future__ import annotations

import collections
import ctypes
import math
import pathlib
import shutil
import struct
import weakref
from ctypes import POINTER, byref, c_char, c_double, c_int, c_size_t, c_uint, c_void_p
from dataclasses import dataclass

from cosim.errors import ComponentError
from cosim.plant import fmufile
from cosim.scenario.vehicles import VehicleParams

__all__ = [
    "OUTPUT_NAMES", "INPUT_NAMES", "FmuPlant", "Plant", "PlantState",
    "Y_X", "Y_Y", "Y_Z", "Y_VX", "Y_VY", "Y_VZ", "Y_QW", "Y_QX", "Y_QY", "Y_QZ",
    "Y_P", "Y_Q", "Y_R", "Y_AX", "Y_AY", "Y_AZ",
    "Y_OMEGA1", "Y_OMEGA2", "Y_OMEGA3", "Y_OMEGA4", "Y_ON_GROUND",
]

#: Plant outputs, in the order of :attr:`Plant.y`. Units: m, m/s (NED), quaternion body->world,
#: rad/s (body FRD), m/s^2 (specific force, body), rad/s (rotors), on_ground as 0.0/1.0.
OUTPUT_NAMES: tuple[str, ...] = (
    "x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "p", "q", "r",
    "ax", "ay", "az", "omega1", "omega2", "omega3", "omega4", "on_ground",
)
#: FMU inputs set on every step: motor commands (1) and wind (m/s, NED).
INPUT_NAMES: tuple[str, ...] = ("u1", "u2", "u3", "u4", "wind_n", "wind_e", "wind_d")

(
    Y_X, Y_Y, Y_Z, Y_VX, Y_VY, Y_VZ, Y_QW, Y_QX, Y_QY, Y_QZ, Y_P, Y_Q, Y_R,
    Y_AX, Y_AY, Y_AZ, Y_OMEGA1, Y_OMEGA2, Y_OMEGA3, Y_OMEGA4, Y_ON_GROUND,
) = range(len(OUTPUT_NAMES))

_N_REAL_OUT = len(OUTPUT_NAMES) - 1  # all but on_ground
_STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")

_Component = c_void_p
_SetRealT = ctypes.CFUNCTYPE(c_int, _Component, POINTER(c_uint), c_size_t, POINTER(c_double))
_GetRealT = _SetRealT
_GetBooleanT = ctypes.CFUNCTYPE(c_int, _Component, POINTER(c_uint), c_size_t, POINTER(c_int))
_DoStepT = ctypes.CFUNCTYPE(c_int, _Component, c_double, c_double, c_int)
_GetStateT = ctypes.CFUNCTYPE(c_int, _Component, POINTER(c_void_p))
_SetStateT = ctypes.CFUNCTYPE(c_int, _Component, c_void_p)
_SerSizeT = ctypes.CFUNCTYPE(c_int, _Component, c_void_p, POINTER(c_size_t))
_SerializeT = ctypes.CFUNCTYPE(c_int, _Component, c_void_p, POINTER(c_char), c_size_t)
_DeSerializeT = ctypes.CFUNCTYPE(c_int, _Component, POINTER(c_char), c_size_t, POINTER(c_void_p))


STEPPER = "cosim.plant._fmi2step"   # the FMI 2.0 stepper binding (csrc/fmi2step.c)


@dataclass(frozen=True)
class PlantState:
    """A snapshot of the plant: the FMU's serialised state and the tick counter."""

    k: int
    fmu_state: bytes


class FmuPlant:
    """What every plant shares (this one and `cosim.plant.mapped.MappedPlant`): the time from
    the tick counter, the FMU's log messages for the errors raised, the refusal to step a
    closed plant, the context manager."""

    k: int
    step_size: float
    _messages: collections.deque[str]

    @property
    def t(self) -> float:
        """Simulated time of the latest outputs, s (= k * step_size)."""
        return self.k * self.step_size

    def _log(self, env, instance_name, status, category, message) -> None:
        """The FMI 2.0 logger callback (FMI 3.0's has no instance name)."""
        text = message.decode("utf-8", "replace") if message else ""
        label = _STATUS[status] if 0 <= status < len(_STATUS) else str(status)
        self._messages.append(f"[{label}] {text}")

    def _drain(self) -> str:
        msgs = "; ".join(self._messages)
        self._messages.clear()
        return msgs or "no message from the FMU"

    def _used_closed(self) -> None:
        """A call into an FMU instance that is freed (or was never made) would crash."""
        raise ComponentError("plant", "the plant is closed (or failed to start)")

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass


class Plant(FmuPlant):
    """The Quadrotor FMU stepped at a fixed tick.

    Parameters
    ----------
    vehicle : VehicleParams
        Airframe; all its fields are set as FMU parameters of the same names.
    step_size : float
        Tick h, s (5 ms = the HIL/control rate). ``t = k * step_size``.
    substep : float
        RK4 substep inside the FMU, s, in (0, 0.001].
    x0, y0, z0 : float
        Initial position of the CG, m, NED. ``z0 >= 0`` means standing on the floor (the
        FMU then starts at the contact equilibrium, 0.25 mm below z = 0).
    yaw0 : float
        Initial heading, rad.
    omega0 : float
        Initial speed of all four rotors, rad/s (e.g. ``vehicle.omega_hover`` to start in
        hover). Extension of the contract; default 0.
    fmu_path : path-like, optional
        The FMU to load; default ``fmus.build.fmu_path()`` (built from source if needed).
    fast : bool
        Use the FMU's ``quadrotorSetStepGet`` if it has one (same results); False: always
        the four standard FMI calls per step.
    """

    def __init__(
        self,
        vehicle: VehicleParams,
        *,
        step_size: float = 0.005,
        substep: float = 0.001,
        x0: float = 0.0,
        y0: float = 0.0,
        z0: float = 0.0,
        yaw0: float = 0.0,
        omega0: float = 0.0,
        fmu_path: str | pathlib.Path | None = None,
        fast: bool = True,
        stepper: bool | None = None,
    ) -> None:
        from fmpy import calloc, free
        from fmpy.fmi2 import (
            FMU2Slave,
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
        )
        from fmpy.logging import addLoggerProxy

        if not (isinstance(step_size, (int, float)) and math.isfinite(step_size)
                and step_size > 0):
            raise ValueError(f"step_size must be a positive number of seconds, got {step_size!r}")
        if not getattr(self, "_closed", True):   # __init__ again: free the instance it has
            self.close()
        self.vehicle = vehicle
        self.step_size = float(step_size)
        self._stepper = None
        self.k = 0
        self._closed = True
        self._messages: collections.deque[str] = collections.deque(maxlen=32)

        if fmu_path is None:
            from fmus.build import fmu_path as _default_fmu_path

            fmu_path = _default_fmu_path()
        self.fmu_path = pathlib.Path(fmu_path)
        md = fmufile.model_description(self.fmu_path)
        vr = {v.name: v.valueReference for v in md.modelVariables}
        missing = [n for n in (*INPUT_NAMES, *OUTPUT_NAMES) if n not in vr]
        if missing:
            raise ComponentError("plant", f"{self.fmu_path} lacks variables {missing}")

        try:             # its binary for this platform; no more than a run needs of it
            self._unzipdir = fmufile.extract(self.fmu_path, 2, md.coSimulation.modelIdentifier)
        except fmufile.FmuFileError as exc:
            raise ComponentError("plant", f"{self.fmu_path} is not {exc}") from None
        self._fmu = FMU2Slave(
            guid=md.guid, unzipDirectory=self._unzipdir,
            modelIdentifier=md.coSimulation.modelIdentifier, instanceName="plant",
        )
        # our own logger so that the FMU's messages end up in the exceptions we raise
        self._logger_cb = fmi2CallbackLoggerTYPE(self._log)
        self._callbacks = fmi2CallbackFunctions()
        self._callbacks.logger = self._logger_cb
        self._callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self._callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        addLoggerProxy(byref(self._callbacks))
        try:
            self._fmu.instantiate(callbacks=self._callbacks)
        except Exception as e:
            shutil.rmtree(self._unzipdir, ignore_errors=True)
            raise ComponentError("plant", f"fmi2Instantiate failed: {e}; {self._drain()}") from e
        self._closed = False
        self._comp = c_void_p(self._fmu.component)

        dll = self._fmu.dll
        self._set_real = _SetRealT(("fmi2SetReal", dll))
        self._get_real = _GetRealT(("fmi2GetReal", dll))
        self._get_bool = _GetBooleanT(("fmi2GetBoolean", dll))
        self._do_step = _DoStepT(("fmi2DoStep", dll))
        self._get_state = _GetStateT(("fmi2GetFMUstate", dll))
        self._set_state = _SetStateT(("fmi2SetFMUstate", dll))
        self._ser_size = _SerSizeT(("fmi2SerializedFMUstateSize", dll))
        self._serialize = _SerializeT(("fmi2SerializeFMUstate", dll))
        self._deserialize = _DeSerializeT(("fmi2DeSerializeFMUstate", dll))
        self._free_state = ctypes.CFUNCTYPE(c_int, _Component, POINTER(c_void_p))(
            ("fmi2FreeFMUstate", dll)
        )

        # preallocated arrays for the hot path
        self._in_vr = (c_uint * len(INPUT_NAMES))(*(vr[n] for n in INPUT_NAMES))
        self._in_val = (c_double * len(INPUT_NAMES))()
        self._out_vr = (c_uint * _N_REAL_OUT)(*(vr[n] for n in OUTPUT_NAMES[:-1]))
        self._out_val = (c_double * _N_REAL_OUT)()
        self._og_vr = (c_uint * 1)(vr["on_ground"])
        self._og_val = (c_int * 1)()
        self._scratch_state = c_void_p()
        # Hot path without ctypes argument conversion: untyped prototypes called with
        # ready-made ctypes objects (pointers cast once, sizes as c_size_t instances), inputs
        # written through a memoryview, outputs read with one struct.unpack.
        self._raw_set_real = ctypes.CFUNCTYPE(c_int)(("fmi2SetReal", dll))
        self._raw_get_real = ctypes.CFUNCTYPE(c_int)(("fmi2GetReal", dll))
        self._raw_get_bool = ctypes.CFUNCTYPE(c_int)(("fmi2GetBoolean", dll))
        self._raw_do_step = ctypes.CFUNCTYPE(c_int)(("fmi2DoStep", dll))
        self._in_mv = memoryview(self._in_val).cast("B").cast("d")
        self._in_vr_p = ctypes.cast(self._in_vr, c_void_p)
        self._in_val_p = ctypes.cast(self._in_val, c_void_p)
        self._out_vr_p = ctypes.cast(self._out_vr, c_void_p)
        self._out_val_p = ctypes.cast(self._out_val, c_void_p)
        self._og_vr_p = ctypes.cast(self._og_vr, c_void_p)
        self._og_val_p = ctypes.cast(self._og_val, c_void_p)
        self._n_in = c_size_t(len(INPUT_NAMES))
        self._n_out = c_size_t(_N_REAL_OUT)
        self._n_og = c_size_t(1)
        self._one = c_int(1)
        self._h = c_double(self.step_size)
        self._unpack_out = struct.Struct(f"{_N_REAL_OUT}d").unpack
        # The FMU's non-standard quadrotorSetStepGet (fmus/quadrotor/fmi2.c) does the four
        # calls of a tick in one ctypes call; any other FMU gets the standard calls.
        self._raw_set_step_get = None
        if fast:
            try:
                self._raw_set_step_get = ctypes.CFUNCTYPE(c_int)(("quadrotorSetStepGet", dll))
            except AttributeError:
                pass

        try:
            params = dict(vehicle.fmu_parameters())
            params.update(x0=x0, y0=y0, z0=z0, yaw0=yaw0, omega0=omega0, substep=substep)
            unknown = sorted(set(params) - set(vr))
            if unknown:
                raise ComponentError("plant", f"the FMU has no parameters {unknown}")
            names = list(params)
            pvr = (c_uint * len(names))(*(vr[n] for n in names))
            pval = (c_double * len(names))(*(float(params[n]) for n in names))
            self._check(self._set_real(self._comp, pvr, len(names), pval), "fmi2SetReal")
            setup = ctypes.CFUNCTYPE(c_int, _Component, c_int, c_double, c_double, c_int,
                                     c_double)(("fmi2SetupExperiment", dll))
            self._check(setup(self._comp, 0, 0.0, 0.0, 0, 0.0), "fmi2SetupExperiment")
            for name in ("fmi2EnterInitializationMode", "fmi2ExitInitializationMode"):
                f = ctypes.CFUNCTYPE(c_int, _Component)((name, dll))
                self._check(f(self._comp), name)
            #: latest outputs in OUTPUT_NAMES order (updated in place by step())
            self.y: list[float] = [0.0] * len(OUTPUT_NAMES)
            self._read_outputs()
            self._use_stepper(stepper)
            self._initial_state = self.get_state()
        except BaseException:
            self.close()
            raise

    # ---- hot path ---------------------------------------------------------------------------

    def step(
        self,
        u1: float,
        u2: float,
        u3: float,
        u4: float,
        wind_n: float = 0.0,
        wind_e: float = 0.0,
        wind_d: float = 0.0,
    ) -> list[float]:
        """Hold the inputs over one tick and advance t_k -> t_k+1; returns :attr:`y`.

        u1..u4 are normalised motor commands (clamped to [0, 1] by the FMU; NaN raises),
        wind_* the wind velocity in m/s, NED. The returned list is :attr:`y`, updated in place.
        """
        if self._closed:
            self._used_closed()
        v = self._in_mv
        v[0] = u1
        v[1] = u2
        v[2] = u3
        v[3] = u4
        v[4] = wind_n
        v[5] = wind_e
        v[6] = wind_d
        fused = self._raw_set_step_get
        if fused is not None:
            st = fused(self._comp, self._in_vr_p, self._n_in, self._in_val_p,
                       c_double(self.k * self.step_size), self._h, self._out_vr_p, self._n_out,
                       self._out_val_p, self._og_vr_p, self._n_og, self._og_val_p)
            if st:
                self._check(st, "quadrotorSetStepGet (fmi2SetReal, fmi2DoStep, fmi2GetReal, "
                                "fmi2GetBoolean)")
            self.k += 1
            y = self.y
            y[:_N_REAL_OUT] = self._unpack_out(self._out_val)
            y[_N_REAL_OUT] = 1.0 if self._og_val[0] else 0.0
            return y
        st = self._raw_set_real(self._comp, self._in_vr_p, self._n_in, self._in_val_p)
        if st:
            self._check(st, "fmi2SetReal")
        st = self._raw_do_step(self._comp, c_double(self.k * self.step_size), self._h, self._one)
        if st:
            self._check(st, "fmi2DoStep")
        self.k += 1
        return self._read_outputs()

    def _read_outputs(self) -> list[float]:
        if self._closed:
            self._used_closed()
        st = self._raw_get_real(self._comp, self._out_vr_p, self._n_out, self._out_val_p)
        if st:
            self._check(st, "fmi2GetReal")
        st = self._raw_get_bool(self._comp, self._og_vr_p, self._n_og, self._og_val_p)
        if st:
            self._check(st, "fmi2GetBoolean")
        y = self.y
        y[:_N_REAL_OUT] = self._unpack_out(self._out_val)
        y[_N_REAL_OUT] = 1.0 if self._og_val[0] else 0.0
        return y

    def _use_stepper(self, want: bool | None) -> None:
        """Bind :meth:`step` to the compiled stepper (see the class docstring): when this run
        is compiled (onesource/switch.py) and `want` is not False; `want` True requires it."""
        from onesource import switch as compiled

        if want is None:
            want = compiled.uses(STEPPER)
        if not want:
            return
        from cosim.plant._fmi2step import Stepper

        def addr(f) -> int:
            return ctypes.cast(f, c_void_p).value or 0

        fns = (addr(self._raw_set_real), addr(self._raw_do_step), addr(self._raw_get_real),
               addr(self._raw_get_bool),
               addr(self._raw_set_step_get) if self._raw_set_step_get is not None else 0)
        me = weakref.ref(self)         # no reference cycle plant -> stepper -> plant

        def on_error(status: int, what: str) -> None:
            me()._check(status, what)

        st = Stepper(fns, self._comp.value, tuple(self._in_vr), tuple(self._out_vr),
                     tuple(self._og_vr), self.step_size, self.y, on_error, INPUT_NAMES)
        st.k = self._k
        self._stepper = st
        self.step = st.step           # the master's per-tick call is the C method itself

    @property
    def k(self) -> int:
        """Ticks stepped since t = 0."""
        st = self._stepper
        return self._k if st is None else st.k

    @k.setter
    def k(self, value: int) -> None:
        if self._stepper is None:
            self._k = value
        else:
            self._stepper.k = value

    # ---- states -----------------------------------------------------------------------------

    def get_state(self) -> PlantState:
        """Snapshot of the FMU state and the tick counter (cheap: a few kB memcpy)."""
        if self._closed:
            self._used_closed()
        self._check(self._get_state(self._comp, byref(self._scratch_state)), "fmi2GetFMUstate")
        size = c_size_t()
        self._check(self._ser_size(self._comp, self._scratch_state, byref(size)),
                    "fmi2SerializedFMUstateSize")
        buf = ctypes.create_string_buffer(size.value)
        self._check(self._serialize(self._comp, self._scratch_state, buf, size.value),
                    "fmi2SerializeFMUstate")
        return PlantState(k=self.k, fmu_state=buf.raw)

    def set_state(self, s: PlantState) -> None:
        """Restore a snapshot from :meth:`get_state` (also restores :attr:`k` and :attr:`y`)."""
        if not isinstance(s, PlantState):
            raise TypeError(f"expected a PlantState from Plant.get_state(), got {type(s).__name__}")
        if self._closed:
            self._used_closed()
        buf = ctypes.create_string_buffer(s.fmu_state, len(s.fmu_state))
        self._check(self._deserialize(self._comp, buf, len(s.fmu_state),
                                      byref(self._scratch_state)), "fmi2DeSerializeFMUstate")
        self._check(self._set_state(self._comp, self._scratch_state), "fmi2SetFMUstate")
        self.k = s.k
        self._read_outputs()

    def reset(self) -> None:
        """Back to t = 0 and the initial state (bit-identical re-runs)."""
        self.set_state(self._initial_state)

    # ---- errors and logging -----------------------------------------------------------------

    def _check(self, status: int, func: str) -> None:
        if status == 0:
            return
        label = _STATUS[status] if 0 <= status < len(_STATUS) else str(status)
        raise ComponentError("plant", f"{func} returned {label} at t = {self.t:.6g} s: "
                                      f"{self._drain()}")

    # ---- life cycle ---------------------------------------------------------------------------

    def close(self) -> None:
        """Free the FMU instance and its extracted files (idempotent)."""
        if self._closed:
            return
        self._closed = True
        st = self._stepper
        bound = self.__dict__.pop("step", None)
        if st is not None:            # no C calls into a freed instance: back to the ctypes path
            self._stepper = None
            self._k = st.k
            st.close()                # a `step` bound elsewhere now raises instead
        if bound is not None and hasattr(getattr(bound, "__self__", None), "close"):
            bound.__self__.close()
        try:
            if self._scratch_state.value:
                self._free_state(self._comp, byref(self._scratch_state))
            self._fmu.freeInstance()
        finally:
            shutil.rmtree(self._unzipdir, ignore_errors=True)
