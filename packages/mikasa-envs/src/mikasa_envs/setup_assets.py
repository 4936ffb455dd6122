"""Generate the assets mikasa-envs derives from ManiSkill's (``python -m mikasa_envs.setup_assets``).

Envs generate them lazily on first use; running this once up front (the setup script does)
keeps that cost out of the first ``gym.make``.
"""

from __future__ import annotations

from mikasa_envs.robot import ROBOT_MESH_CHOICES, light_panda_urdf


def main() -> None:
    """Create both robot descriptions in the cache and print their paths."""
    for meshes in ROBOT_MESH_CHOICES:
        print(f"panda_wristcam description ({meshes} meshes): {light_panda_urdf(meshes)}")


if __name__ == "__main__":
    main()
