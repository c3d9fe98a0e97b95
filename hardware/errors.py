"""Typed errors of the hardware layer; each message says what is wrong and what to do."""

from __future__ import annotations

from studio.errors import StudioError


class HardwareError(StudioError):
    """Base class of every servo-bus, calibration and playback error."""


class ProtocolError(HardwareError):
    """Bytes that are not a valid LX-15D packet."""


class ChecksumError(ProtocolError):
    """A packet arrived whose checksum does not match: noise on the bus or two servos answering at once."""


class UnexpectedReply(ProtocolError):
    """A valid packet arrived that is not the answer that was asked for (wrong ID, command or echo)."""


class ServoTimeout(HardwareError):
    """A servo did not answer in time."""

    def __init__(self, servo_id: int, message: str | None = None):
        self.servo_id = servo_id
        super().__init__(message or f"servo {servo_id} did not answer: check its cable, power and ID")


class ServoFault(HardwareError):
    """A servo reports a fault (over-temperature, over-voltage, locked rotor) or a reading outside safe bounds."""

    def __init__(self, servo_id: int, message: str):
        self.servo_id = servo_id
        super().__init__(message)


class BusError(HardwareError):
    """The serial port cannot be opened or used (every pyserial, OS and termios error of the port becomes one)."""


class EStopLatched(HardwareError):
    """A motion command was refused because the e-stop is latched, in this process or in its file (any process);
    ``reset_estop()`` clears it (a face says how: ``shadow-studio estop --reset``, the Jog panel's reset)."""

    def __init__(self, message: str, sent: dict[int, int] | None = None):
        self.sent = dict(sent or {})  # {id: units} that went out before the latch refused the rest
        super().__init__(message)


class EStopResetFailed(EStopLatched):
    """The e-stop could not be reset (its file cannot be removed): it stays latched."""


class ShowForAnotherHand(HardwareError):
    """A show planned for another hand model (URDF) than the one these servos drive (refused unless forced)."""


class CalibrationError(HardwareError):
    """A calibration file does not match the hand, is inconsistent, or cannot be written where asked."""


class CalibrationMissing(CalibrationError, FileNotFoundError):
    """No calibration file where one was asked for (a face says how it makes one)."""


class OverTemperature(ServoFault):
    """A servo is hotter than the safe limit."""


class MountMismatch(CalibrationError):
    """A show made for one mount roll, and a calibration that records the rig at another."""


class CameraError(HardwareError):
    """A camera (a device, a video file played as one, a frame folder) cannot be opened or read."""


class CameraAbsent(CameraError):
    """No camera where one was asked for: no device at that index, no such video file or frame folder, or a
    source OpenCV cannot open."""


class CameraStalled(CameraError):
    """A camera that was open delivered no new frame in time (a cable pulled, a driver hung, a source that froze)."""


class CameraEnded(CameraError):
    """A video file or frame folder played as a camera (without looping) reached its end: no newer frame will come."""
