"""The worker pool: processes that take jobs from the durable ``jobs`` table and run them.

- ``workers.handlers``: the registry ``HANDLERS`` (job kind -> handler) where the method plugs in.
- ``workers.worker``: one worker process's loop (claim, lease heartbeat, retry, graceful stop).
- ``workers.supervisor``: starts, restarts and stops child processes (workers and the API).
- ``workers.broker`` and ``workers.celery_worker``: the distributed profile, where Celery on Redis carries
  job ids to workers that claim and run them with the same machinery, and a reconciler republishes lost ids.
"""
