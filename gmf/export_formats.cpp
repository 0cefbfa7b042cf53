// placeholder (issue 8)
