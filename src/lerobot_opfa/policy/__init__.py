"""The `opfa` LeRobot policy: configuration, model, processors (modules named as LeRobot expects)."""
