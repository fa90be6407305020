"""Applications built on the features: object retrieval (`retrieval`), template tracking
(`tracking`) and the object mask they share (`objectmask`)."""
