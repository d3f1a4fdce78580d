"""YAML -> spec -> flat diagram -> port graph -> schedule -> generated code."""
