"""Tasks: what the end effector must do (Chapters 2 and 4)."""
