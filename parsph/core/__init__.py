"""The SPH core: the particle store, the kernel, neighbour lists, summation density, contact, tensors."""
