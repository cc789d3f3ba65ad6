"""The worker pool: processes that take jobs from the durable ``jobs`` table and run them.

- ``workers.handlers``: the registry ``HANDLERS`` (job kind -> handler) where the method plugs in.
- ``workers.worker``: one worker process's loop (claim, lease heartbeat, retry, graceful stop).
- ``workers.supervisor``: starts, restarts and stops child processes (workers and the API).
"""
