"""Pin assignment of the ESP32 status panel (ESP32-DevKitC, ESP32-WROOM-32); must match hw/wiring.yaml.

ESP32 GPIO numbers. The LCD (Newhaven NHD-0420H1Z-FSW-GBW-33V3, HD44780/ST7066U class, 3.3 V logic) is driven in
4-bit mode with R/W tied to GND (write only). Buttons (E-Switch PVA6) close to GND; the firmware enables the internal
pull-ups, so pressed = 0. Strapping pins (0, 2, 5, 12, 15), flash pins (6-11) and input-only pins (34-39) are avoided.
UART_TX/UART_RX are the optional UART2 link (a USB-UART adapter) used when the USB console is not the link.
"""

LCD_RS = 19
LCD_E = 18
LCD_D4 = 21
LCD_D5 = 22
LCD_D6 = 23
LCD_D7 = 25
BTN_SENSORS = 26
BTN_RECORD = 27
UART_TX = 17
UART_RX = 16
UART_ID = 2
UART_BAUDRATE = 115200  # matches panel.baudrate of the rig config (a few hundred bytes/s of traffic)
