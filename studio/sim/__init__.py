"""The robot and its world: the hand (URDF), differentiable FK, the exact shadow renderer and its PyBullet reference,
the collision world and the self-exploration sampler. The ground floor: imports nothing else of ``studio``."""
