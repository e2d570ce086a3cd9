"""Building the docs site: the reference tables generated from the code, and the manual's word count."""
