"""What the job layer refuses, as domain errors; ``app.api.problems`` maps each to its HTTP problem."""

from __future__ import annotations


class JobError(Exception):
    """Base of the job layer's refusals."""


class JobNotFound(JobError):
    def __init__(self, kind: str, job_id: str):
        shown = job_id if len(job_id) <= 64 else job_id[:64] + "..."
        super().__init__(f"no {kind} job with id {shown!r}")
        self.kind, self.job_id = kind, job_id


class JobAlreadyFinished(JobError):
    def __init__(self, job_id: str, status: str):
        super().__init__(f"job {job_id} already finished with status {status!r}; it cannot be cancelled")
        self.job_id, self.status = job_id, status


class QueueFull(JobError):
    def __init__(self, queued: int, limit: int, retry_after: int):
        super().__init__(f"the queue holds {queued} jobs, the limit is {limit} (NCS_MAX_QUEUE_DEPTH); "
                         f"retry after {retry_after} s")
        self.retry_after = retry_after


class OwnerQueueFull(QueueFull):
    """This caller's own quota of queued jobs is used up (other API keys are not affected)."""

    def __init__(self, queued: int, limit: int, retry_after: int):
        JobError.__init__(self, f"your API key has {queued} jobs queued, its limit is {limit} "
                          f"(NCS_MAX_QUEUED_PER_OWNER); other keys are not affected; retry after {retry_after} s, "
                          f"when some of your jobs have started")
        self.retry_after = retry_after
        self.queued, self.limit = queued, limit


class IdempotencyKeyReused(JobError):
    def __init__(self) -> None:
        super().__init__("this Idempotency-Key was already used with a different request body")


class ComputeTimeLimit(JobError):
    def __init__(self, task: str, seconds: float):
        super().__init__(f"the {task} took longer than {seconds:g} s (NCS_SYNC_TIME_LIMIT) and was stopped")


class WorkerDied(JobError):
    def __init__(self, task: str):
        super().__init__(f"the {task} worker process died; try again")


class MemoryLimitExceeded(JobError):
    def __init__(self, message: str):
        super().__init__(message)


class InvalidComputeInput(JobError):
    """The solver rejected an input the request checks let through; ``field`` is its path in the request."""

    def __init__(self, field: tuple, message: str):
        super().__init__(message)
        self.field = field


class ComputeFailed(JobError):
    pass
