"""The simulated backpack: fake GigE cameras serving a synthetic world, trigger and panel simulators, the daemon."""
