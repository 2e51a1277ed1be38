"""Entry points: rollout (main job), bench."""
