"""Session engine: clocks, the trial loop, timers, prompts, questionnaires and resume."""
