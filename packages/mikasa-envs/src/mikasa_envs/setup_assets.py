"""Generate the assets mikasa-envs derives from ManiSkill's (``python -m mikasa_envs.setup_assets``).

Envs generate them lazily on first use; running this once up front (the setup script does)
keeps that cost out of the first ``gym.make``.
"""

from __future__ import annotations

from mikasa_envs.robot import light_panda_urdf


def main() -> None:
    """Create both light robot descriptions in the cache and print their paths."""
    for light_links in (False, True):
        print(f"light panda_wristcam description (light links: {light_links}): {light_panda_urdf(light_links)}")


if __name__ == "__main__":
    main()
