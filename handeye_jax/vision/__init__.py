"""The camera's pictures: landmark detection and matching in a colour and depth picture
(OpenCV), and the pictures to take (capture planning)."""
