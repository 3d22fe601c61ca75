"""Image features: ORB extraction, descriptor matching, the bag-of-words vocabulary and the frames that carry them."""
