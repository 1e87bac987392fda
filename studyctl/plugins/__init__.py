"""Plugin interfaces (controllers, devices, scenes, participants) and their discovery."""
