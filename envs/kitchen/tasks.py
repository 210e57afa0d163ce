"""FrankaKitchen task vocabulary: the six TALAR sub-tasks; goal id = index in ``TASK_NAMES``."""

from __future__ import annotations

# Order of the paper's listing (Appendix D.1.1) and of the instruction data.
TASK_NAMES: tuple[str, ...] = ("microwave", "kettle", "light switch", "slide cabinet", "top burner", "bottom burner")
NUM_TASKS = len(TASK_NAMES)
