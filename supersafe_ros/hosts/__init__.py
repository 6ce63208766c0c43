"""Running the team across hosts: network namespaces (netns) and node placement (placement)."""
