"""dexmots_rl: DexMOTS dexterous manipulation with a differentiable warp simulator, TorchRL-native."""

from __future__ import annotations

__version__ = "0.1.0"
__all__ = ["__version__", "make_env"]


def make_env(*args, **kwargs):
    """Shortcut for :func:`dexmots_rl.envs.make_env`."""
    from .envs import make_env as _make_env

    return _make_env(*args, **kwargs)
