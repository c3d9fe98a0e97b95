"""One virtual LX-15D servo: its registers and its motion, as the emulator's bus thread drives it.

Motion follows the datasheet: a move command turns the servo "from its current angle to the target at uniform
speed within the given time", never faster than the servo's top speed. Positions are servo units (0..1000).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hardware import constants as C


@dataclass
class VirtualServo:
    """Registers and motion state of one servo."""

    servo_id: int  # current ID (ID_WRITE changes it)
    start_units: float  # encoder position at power-on, units
    speed_units_s: float = C.SERVO_SPEED_UNITS_S  # top speed, units/s
    torque: bool = False  # motor loaded (servos power on unloaded; a move loads them)
    offset: int = 0  # angle offset, units (-125..125)
    saved_offset: int = 0  # offset kept after power-off
    angle_limits: tuple[int, int] = (0, C.POS_UNITS)  # min, max commandable position
    vin_limits: tuple[int, int] = C.DEFAULT_VIN_LIMITS_MV  # mV
    temp_limit: int = C.DEFAULT_TEMP_LIMIT_C  # °C
    motor_mode: tuple[int, int, int] = (0, 0, 0)  # mode, 0, speed
    vin_offset_mv: int = 0  # this unit's voltage reading minus the bus voltage (no two units read alike)
    temp_offset_c: int = 0  # this unit's temperature minus the bus's healthy temperature
    led_off: int = 0  # LED_CTRL value
    led_error_mask: int = 7  # which faults flash the LED
    stuck: bool = False  # locked rotor (set by the emulator's fault table)
    hot_c: int | None = None  # forced temperature when overheating (set by the fault table)
    locked_rotor: bool = False  # latched: a move was commanded while the rotor was locked
    last_move: tuple[int, int] = (C.CENTER_UNITS, 0)  # last MOVE_TIME_WRITE: position, time ms
    waiting_move: tuple[int, int] | None = None  # MOVE_TIME_WAIT_WRITE held until MOVE_START
    _p0: float = field(init=False)  # physical position where the current move started, units
    _p1: float = field(init=False)  # physical target of the current move, units
    _t0: float = field(init=False, default=0.0)  # perf_counter time the move started, s
    _dt: float = field(init=False, default=0.0)  # move duration, s

    def __post_init__(self) -> None:
        self._p0 = self._p1 = float(self.start_units)

    def position(self, now: float) -> float:
        """Physical encoder position at ``now``, units."""
        if self._dt <= 0 or now >= self._t0 + self._dt:
            return self._p1
        a = max(0.0, (now - self._t0) / self._dt)
        return self._p0 + (self._p1 - self._p0) * a

    def push(self, units: float, now: float) -> None:
        """Move the horn by hand (ignored while torque holds it)."""
        if not self.torque:
            self._p0 = self._p1 = float(units)
            self._dt = 0.0

    def _move(self, target: int, ms: int, now: float) -> None:
        self.torque = True
        here = self.position(now)
        if self.stuck:
            self._p0 = self._p1 = here
            self._dt = 0.0
            if abs(target + self.offset - here) > 2:
                self.locked_rotor = True
            return
        lo, hi = self.angle_limits
        goal = float(min(max(target, lo), hi) + self.offset)
        self._p0, self._p1, self._t0 = here, goal, now
        self._dt = max(ms / 1000.0, abs(goal - here) / self.speed_units_s)

    def _halt(self, now: float) -> None:
        self._p0 = self._p1 = self.position(now)
        self._dt = 0.0

    def faults(self, temp_c: int) -> int:
        bits = 0
        if temp_c >= self.temp_limit or self.hot_c is not None:
            bits |= C.FAULT_OVER_TEMPERATURE
        if self.locked_rotor or self.stuck and self.torque:
            bits |= C.FAULT_LOCKED_ROTOR
        return bits

    def apply(self, command: C.Command, values: tuple[int, ...], now: float, cfg) -> tuple[int, ...] | None:
        """Act on one request; return the answer's values for a read command, None for a write."""
        code = command.code
        temp = self.hot_c if self.hot_c is not None else cfg.temp_c + self.temp_offset_c
        if code == C.MOVE_TIME_WRITE.code:
            self.last_move = (values[0], values[1])
            self._move(values[0], values[1], now)
        elif code == C.MOVE_TIME_WAIT_WRITE.code:
            self.waiting_move = (values[0], values[1])
        elif code == C.MOVE_START.code and self.waiting_move is not None:
            self.last_move = self.waiting_move
            self._move(*self.waiting_move, now)
            self.waiting_move = None
        elif code == C.MOVE_STOP.code:
            self._halt(now)
        elif code == C.ID_WRITE.code and values[0] <= C.MAX_ID:
            self.servo_id = values[0]
        elif code == C.ANGLE_OFFSET_ADJUST.code:
            here = self.position(now) - self.offset
            self.offset = max(C.OFFSET_MIN, min(C.OFFSET_MAX, values[0]))
            if self.torque:  # the horn shifts so that the same commanded position lands offset away
                self._p0 = self._p1 = here + self.offset
                self._dt = 0.0
        elif code == C.ANGLE_OFFSET_WRITE.code:
            self.saved_offset = self.offset
        elif code == C.ANGLE_LIMIT_WRITE.code and values[0] < values[1] <= C.POS_UNITS:
            self.angle_limits = (values[0], values[1])
        elif code == C.VIN_LIMIT_WRITE.code and values[0] < values[1]:
            self.vin_limits = (values[0], values[1])
        elif code == C.TEMP_MAX_LIMIT_WRITE.code:
            self.temp_limit = min(100, max(50, values[0]))
        elif code == C.OR_MOTOR_MODE_WRITE.code:
            self.motor_mode = (values[0], 0, values[2])
        elif code == C.LOAD_OR_UNLOAD_WRITE.code:
            self.torque = bool(values[0])
            if not self.torque:
                self._halt(now)
        elif code == C.LED_CTRL_WRITE.code:
            self.led_off = values[0]
        elif code == C.LED_ERROR_WRITE.code:
            self.led_error_mask = values[0] & 7
        elif command.is_read:
            return self._read(code, now, temp, cfg)
        return None

    def _read(self, code: int, now: float, temp: int, cfg) -> tuple[int, ...]:
        reads = {
            C.MOVE_TIME_READ.code: lambda: self.last_move,
            C.MOVE_TIME_WAIT_READ.code: lambda: self.waiting_move or (0, 0),
            C.ID_READ.code: lambda: (self.servo_id,),
            C.ANGLE_OFFSET_READ.code: lambda: (self.offset,),
            C.ANGLE_LIMIT_READ.code: lambda: self.angle_limits,
            C.VIN_LIMIT_READ.code: lambda: self.vin_limits,
            C.TEMP_MAX_LIMIT_READ.code: lambda: (self.temp_limit,),
            C.TEMP_READ.code: lambda: (temp,),
            C.VIN_READ.code: lambda: (cfg.vin_mv + self.vin_offset_mv,),
            C.POS_READ.code: lambda: (int(round(self.position(now) - self.offset)),),
            C.OR_MOTOR_MODE_READ.code: lambda: self.motor_mode,
            C.LOAD_OR_UNLOAD_READ.code: lambda: (int(self.torque),),
            C.LED_CTRL_READ.code: lambda: (self.led_off,),
            C.LED_ERROR_READ.code: lambda: (self.faults(temp),),
        }
        return tuple(reads[code]())
