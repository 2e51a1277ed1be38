"""dexmots_rl: DexMOTS dexterous manipulation with a differentiable warp simulator, TorchRL-native.

Importing the package registers the gymnasium ids ``dexmots/<TaskName>-v0`` (:mod:`.gym_ids`)."""

from __future__ import annotations

from .gym_ids import register_when_gymnasium_loads

__version__ = "0.1.0"
__all__ = ["__version__", "make_env"]


def make_env(*args, **kwargs):
    """Shortcut for :func:`dexmots_rl.envs.make_env`."""
    from .envs import make_env as _make_env

    return _make_env(*args, **kwargs)


register_when_gymnasium_loads()  # gymnasium.make("dexmots/ScrewClaw-v0") works after ``import dexmots_rl``
