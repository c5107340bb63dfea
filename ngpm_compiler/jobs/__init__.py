"""Jobs: the worker pool, the backends that run jobs on it (local processes, Ray), the Ray
reaper, and the one driver loop that trace recording and evaluation runs share."""
