"""``thermal-comp prior``: building, caching and storing a machine type's prior, and its training
programmes."""
