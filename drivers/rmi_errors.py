"""FANUC RMI ErrorID numbers (Remote Motion Interface operator's manual B-84184EN, appendix
"RMI ErrorID reference"): ``ErrorID = 2556928 + N`` for alarm RMIT-N. Facts shared by the driver
(readable messages) and the protocol peer (the codes it answers with).

Only the numbers and names reported identically by several independent sources are listed; the
driver prints any other code as ``RMIT-NNN`` or ``ErrorID N``.
"""

from __future__ import annotations

RMIT_BASE = 2556928

RMIT_NAMES: dict[int, str] = {
    1: "Internal System Error",
    2: "Invalid UTool Number",
    3: "Invalid UFrame Number",
    4: "Invalid Position Register",
    5: "Invalid Speed Override",
    6: "Cannot Execute TP program",
    7: "Controller Servo is Off",
    9: "RMI is Not Running",
    10: "TP Program is Not Paused",
    11: "Cannot Resume TP Program",
    12: "Cannot Reset Controller",
    13: "Invalid RMI Command",
    14: "RMI Command Fail",
    15: "Invalid Controller State",
    16: "Please Cycle Power",
    17: "Invalid Payload Schedule",
    18: "Invalid Motion Option",
    19: "Invalid Vision Register",
    20: "Invalid RMI Instruction",
    21: "Invalid Value",
    22: "Invalid Text String",
    23: "Invalid Position Data",
    24: "RMI is In HOLD State",
    25: "Remote Device Disconnected",
    26: "Robot is Already Connected",
    27: "Wait for Command Done",
    28: "Wait for Instruction Done",
    29: "Invalid sequence ID number",
    30: "Invalid Speed Type",
    31: "Invalid Speed Value",
    32: "Invalid Term Type",
    33: "Invalid Term Value",
    36: "Invalid Destination Position",
    39: "Invalid Group Number",
    40: "Invalid Group Mask",
    43: "Robot in Single Step Mode",
    49: "Invalid Instruction packet",
}


#: FRC_ReadError's ErrorData when the controller has no error to report (as a controller
#: answers), and the most alarms one FRC_ReadError returns (its Count, 1..5: B-84184EN 2.3.5).
NO_ERROR_TEXT = "No Error"
READ_ERROR_MAX_COUNT = 5


def rmit(n: int) -> int:
    """The ErrorID of alarm RMIT-n."""
    return RMIT_BASE + n


INTERNAL_ERROR = rmit(1)
INVALID_UTOOL = rmit(2)
INVALID_UFRAME = rmit(3)
INVALID_OVERRIDE = rmit(5)
SERVO_OFF = rmit(7)
NOT_RUNNING = rmit(9)
INVALID_COMMAND = rmit(13)
COMMAND_FAIL = rmit(14)
INVALID_STATE = rmit(15)
INVALID_INSTRUCTION = rmit(20)
INVALID_VALUE = rmit(21)
ALREADY_CONNECTED = rmit(26)
INVALID_SEQUENCE = rmit(29)
INVALID_SPEED_TYPE = rmit(30)
INVALID_SPEED = rmit(31)
INVALID_TERM_TYPE = rmit(32)
INVALID_DESTINATION = rmit(36)
INVALID_GROUP = rmit(39)
INVALID_GROUP_MASK = rmit(40)


def describe_error(code: int) -> str:
    """``RMIT-013 Invalid RMI Command (2556941)``, or ``ErrorID N`` for another number."""
    n = code - RMIT_BASE
    if 0 < n < 1000:
        name = RMIT_NAMES.get(n, "")
        return f"RMIT-{n:03d}{' ' + name if name else ''} ({code})"
    return f"ErrorID {code}"
