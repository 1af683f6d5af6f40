"""Messages <-> roger_memory core types."""

from __future__ import annotations

import numpy as np
from std_msgs.msg import Header

from roger_common.conversions import seconds_to_time
from roger_common.errors import MessageError
from roger_common.types import FEATURE_DIM, MatchOutcome, MatchResult, MemoryOp, MemoryRequest
from roger_interfaces.msg import MemoryRequest as MemoryRequestMsg
from roger_interfaces.msg import MemoryResult


def msg_to_request(msg: MemoryRequestMsg) -> MemoryRequest:
    """A request message as a core MemoryRequest. Raises MessageError when unusable."""
    try:
        op = MemoryOp(msg.op)
    except ValueError:
        raise MessageError(f"request {msg.request_id}: unknown op {msg.op} (0 match, 1 store)")
    features = np.asarray(msg.features, dtype=np.float32)
    known = np.asarray(msg.known, dtype=bool)
    if features.shape != (FEATURE_DIM,) or known.shape != (FEATURE_DIM,):
        raise MessageError(f"request {msg.request_id}: {features.size} features and "
                           f"{known.size} known flags, expected {FEATURE_DIM} each")
    if not np.all(np.isfinite(features[known])):
        raise MessageError(f"request {msg.request_id}: NaN or infinite features")
    if features[known].size and (features[known].min() < -1e-6
                                 or features[known].max() > 1 + 1e-6):
        raise MessageError(f"request {msg.request_id}: features outside [0, 1]")
    return MemoryRequest(request_id=int(msg.request_id), op=op,
                         features=np.clip(np.nan_to_num(features), 0.0, 1.0), known=known,
                         final_trial=bool(msg.final_trial))


def request_to_msg(req: MemoryRequest, stamp: float) -> MemoryRequestMsg:
    """A core MemoryRequest as a message."""
    return MemoryRequestMsg(header=Header(stamp=seconds_to_time(stamp)),
                            request_id=int(req.request_id), op=int(req.op),
                            features=[float(v) for v in req.features],
                            known=[bool(k) for k in req.known], final_trial=req.final_trial)


def result_to_msg(request_id: int, op: MemoryOp, result: MatchResult, memory_size: int,
                  stamp: float) -> MemoryResult:
    """A core MatchResult as the reply to request ``request_id``."""
    return MemoryResult(header=Header(stamp=seconds_to_time(stamp)), request_id=int(request_id),
                        op=int(op), outcome=int(result.outcome), address=int(result.address),
                        confidence=float(result.confidence), memory_size=int(memory_size))


def msg_to_result(msg: MemoryResult) -> MatchResult:
    """A reply message as a core MatchResult."""
    return MatchResult(outcome=MatchOutcome(msg.outcome), address=int(msg.address),
                       confidence=float(msg.confidence))
