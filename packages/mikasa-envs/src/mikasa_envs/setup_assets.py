"""Generate the assets mikasa-envs derives from ManiSkill's (``python -m mikasa_envs.setup_assets``).

Envs generate them lazily on first use; running this once up front (the setup script does)
keeps that cost out of the first ``gym.make``.
"""

from __future__ import annotations

from mikasa_envs.robot import light_panda_urdf


def main() -> None:
    """Create the light wrist-camera robot description in the cache and print its path."""
    print(f"light panda_wristcam description: {light_panda_urdf()}")


if __name__ == "__main__":
    main()
