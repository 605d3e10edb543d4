"""Running episodes and scoring them: the one episode loop (``rollout``), the one worker
pool (``pool``), the runner that evaluates many designs on it, ``evaluate`` for one
design, the thesis's score ``f = R/(e + 1)^ξ`` (``score``) and the t-interval every
result is reported with (``stats``). It builds on the world and on control.
"""
