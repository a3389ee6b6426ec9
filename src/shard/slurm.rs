//! Slurm: the batch scripts that run a scene's parts as an array job and merge them.
